"""Mountain Car images and data set D: headless rendering, the paper's contrast and blur, shapes and ranges."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import percver as pv
from percver.cases import mountain_car as mc
from percver.errors import InputError, MissingFileError, ParseError

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
POSITIONS = np.array([-1.1, -0.8, -0.5, -0.2, 0.1, 0.4])


def _reference_contrast(image, factor):
    """PIL's ImageEnhance.Contrast written out: 8-bit levels, integer mean, blend, clip, truncate."""
    levels = np.round(image * 255).astype(int)
    mean = int(levels.mean() + 0.5)
    blended = mean + factor * (levels - mean)
    return np.trunc(np.clip(blended, 0, 255)) / 255


def _reference_blur(p, delta):
    """Appendix A.3: 0.5 g(p - d) + g(p) + 0.5 g(p + d), then min-max normalised to [0, 1]."""
    overlay = 0.5 * mc.render([p - delta])[0] + mc.render([p])[0] + 0.5 * mc.render([p + delta])[0]
    return (overlay - overlay.min()) / (overlay.max() - overlay.min())


def test_rendering_is_headless():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")}
    code = "from percver.cases import mountain_car as mc; im = mc.render([-0.5]); print(im.shape, float(im.max()))"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split(")")[0] == "(1, 20, 30"


def test_canonical_images():
    images = mc.render(POSITIONS)
    assert images.shape == (len(POSITIONS), 20, 30)
    assert images.min() >= 0.0 and images.max() <= 1.0
    # dark background, bright car, moving right with the position
    assert np.median(images) < 0.01
    assert np.all(images.reshape(len(POSITIONS), -1).max(axis=1) > 0.9)
    columns = np.arange(30)
    weight = images.sum(axis=1)
    centre = (weight * columns).sum(axis=1) / weight.sum(axis=1)
    assert np.all(np.diff(centre) > 0)


def test_rendering_matches_the_authors_generator():
    """Our enlarged-car rendering against the authors' trained generator (their images are not public)."""
    generator = pv.load_network(mc.paper_dir(SHARED) / "Generator2x50_100_Decay1TestLoss1.035e-06.yml")
    p = np.linspace(-1.2, 0.6, 60)
    difference = np.abs(mc.render(p).reshape(60, 600) - generator(p[:, None]))
    assert difference.mean() < 0.015


@pytest.mark.parametrize("factor", [0.0, 0.3, 1.0, 1.37, 2.0])
def test_contrast_is_pils_definition(factor):
    images = mc.render(POSITIONS[:3])
    out = mc.contrast(images, factor)
    for image, result in zip(images, out):
        np.testing.assert_allclose(result, _reference_contrast(image, factor), atol=1e-12)
    if factor == 0.0:
        assert np.all(np.ptp(out.reshape(3, -1), axis=1) == 0)  # a flat grey image
    if factor == 1.0:
        np.testing.assert_allclose(out, images, atol=0.5 / 255 + 1e-12)  # the image, up to 8-bit rounding


def test_contrast_per_image_factors():
    images = mc.render(POSITIONS[:2])
    both = mc.contrast(images, [0.5, 1.5])
    np.testing.assert_array_equal(both[1], mc.contrast(images[1:], 1.5)[0])
    with pytest.raises(InputError, match="one value per image"):
        mc.contrast(images, [0.5, 1.0, 1.5])


@pytest.mark.parametrize("delta", [0.0, 0.07, 0.3])
def test_blur_is_the_papers_definition(delta):
    out = mc.blur([-0.5], delta)[0]
    np.testing.assert_allclose(out, _reference_blur(-0.5, delta), atol=1e-12)
    assert out.min() == 0.0 and out.max() == pytest.approx(1.0)


def test_validation_blur_effect_uses_the_same_definition():
    camera = mc.canonical_camera().with_effect(pv.validate.effects.get("blur", delta=0.1))
    np.testing.assert_allclose(camera.images(np.array([[-0.5], [0.2]])), mc.blur([-0.5, 0.2], 0.1), atol=1e-12)


def test_composite_blurs_the_contrasted_scene():
    p, dc, db = 0.1, 0.6, 0.1
    scene = [mc.contrast(mc.render([x]), dc)[0] for x in (p - db, p, p + db)]
    overlay = 0.5 * scene[0] + scene[1] + 0.5 * scene[2]
    expected = (overlay - overlay.min()) / np.ptp(overlay)
    np.testing.assert_allclose(mc.observe([p], delta_c=dc, delta_b=db)[0], expected, atol=1e-12)


def test_dataset_shapes_ranges_and_seed(tmp_path):
    data = mc.generate(7, 3, seed=5, progress=False)
    assert len(data) == 7 * (1 + 2 * 3)
    assert data.positions[0] == -1.2 and data.positions[-1] == pytest.approx(0.6)
    assert data.canonical.shape == (7, 20, 30) and data.contrast.shape == data.blur.shape == (7, 3, 20, 30)
    assert data.delta_c.shape == data.delta_b.shape == (7, 3)
    for images in (data.canonical, data.contrast, data.blur):
        assert images.dtype == np.float32 and images.min() >= 0.0 and images.max() <= 1.0
    # one noise level per third of each range (stratified)
    for deltas, (lo, hi) in ((data.delta_c, (0.3, 2.0)), (data.delta_b, (0.0, 0.3))):
        slices = np.floor((deltas - lo) / (hi - lo) * 3)
        assert np.all(slices == np.arange(3))
    np.testing.assert_allclose(data.contrast[2, 1], mc.contrast(data.canonical[2:3].astype(float), data.delta_c[2, 1])[0], atol=1e-6)
    np.testing.assert_allclose(data.blur[4, 2], mc.blur([data.positions[4]], data.delta_b[4, 2])[0], atol=1e-6)

    again = mc.generate(7, 3, seed=5, progress=False)
    np.testing.assert_array_equal(again.blur, data.blur)
    assert not np.array_equal(mc.generate(7, 3, seed=6, progress=False).delta_c, data.delta_c)
    grid = mc.generate(3, 4, stratified=False, progress=False)
    np.testing.assert_allclose(grid.delta_b, np.tile(np.linspace(0, 0.3, 4), (3, 1)))

    path = data.save(tmp_path / "d.npz")
    loaded = mc.Dataset.load(path)
    np.testing.assert_array_equal(loaded.contrast, data.contrast)
    assert loaded.meta["seed"] == 5
    images, targets = loaded.images()
    assert images.shape == (len(data), 600) and targets.shape == (len(data),)


def test_dataset_errors_name_the_file_and_field(tmp_path):
    with pytest.raises(MissingFileError, match="percver cases mountain-car data"):
        mc.Dataset.load(tmp_path / "none.npz")
    data = mc.generate(2, 1, progress=False)
    fields = {name: getattr(data, name) for name in mc.Dataset.FIELDS}
    np.savez(tmp_path / "short.npz", **{k: v for k, v in fields.items() if k != "blur"})
    with pytest.raises(ParseError, match=r"short.npz: missing field\(s\) \['blur'\]"):
        mc.Dataset.load(tmp_path / "short.npz")
    np.savez(tmp_path / "shape.npz", **{**fields, "contrast": fields["contrast"][:, :, :10]})
    with pytest.raises(ParseError, match="field 'contrast' has shape"):
        mc.Dataset.load(tmp_path / "shape.npz")
    with pytest.raises(InputError):
        mc.generate(1, 1, progress=False)
    with pytest.raises(InputError, match="overflow"):
        mc.render([0.0, 40.0])
