"""The knob sweep's scenes at every preset against their stored frames (lab/garment_lab/golden.py):
a refactor keeps the images; a change meant to alter them stores them anew
(`python -m garment_lab.golden --store`) and says so."""

import numpy as np
import pytest

from garment_lab.golden import GOLDEN_FILE, golden_frames
from renderer.presets import PRESET_NAMES
from renderer.reference import relative_rmse


def test_every_stored_frame_is_of_a_preset_that_exists():
    assert {key.rsplit("/", 1)[1] for key in np.load(GOLDEN_FILE).files} == set(PRESET_NAMES)


@pytest.mark.parametrize("preset", PRESET_NAMES)   # a preset a test: parallel runs share them out
def test_the_bench_scenes_render_their_stored_frames(renderer, preset):
    stored = np.load(GOLDEN_FILE)
    frames = golden_frames(renderer, (preset,))
    assert set(frames) <= set(stored.files) and len(frames) >= 1
    for key, image in frames.items():
        want = stored[key].astype(np.float32)
        covered = want[..., 3] > 0.5
        assert covered.sum() > 100, key
        # float16 storage rounds at ~5e-4; another GPU's compiler at far less.
        assert relative_rmse(image, want, covered) < 2e-3, key
        assert np.array_equal(image[..., 3] > 0.5, covered), key
