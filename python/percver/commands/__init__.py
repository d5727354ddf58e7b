"""One module per ``percver`` sub-command (registered in ``percver.cli.COMMANDS``)."""
