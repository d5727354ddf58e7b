"""``percver demo``: the main job on an embedded default."""


def register(sub) -> None:
    parser = sub.add_parser("demo", help="run the embedded default job and write a plot")
    parser.add_argument("--out", default="percver-demo.png", help="PNG file to write (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(func=run)


def run(args) -> int:
    raise NotImplementedError("demo lands with the flowpipe engine")
