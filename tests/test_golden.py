"""The knob sweep's scenes at every preset against their stored frames (renderer/bench/golden.py):
a refactor keeps the images; a change meant to alter them stores them anew
(`python -m renderer.bench.golden --store`) and says so."""

import numpy as np

from renderer.bench.golden import GOLDEN_FILE, golden_frames
from renderer.reference import relative_rmse


def test_the_bench_scenes_render_their_stored_frames(renderer):
    stored = np.load(GOLDEN_FILE)
    frames = golden_frames(renderer)
    assert set(frames) <= set(stored.files) and len(frames) >= 3
    for key, image in frames.items():
        want = stored[key].astype(np.float32)
        covered = want[..., 3] > 0.5
        assert covered.sum() > 100, key
        # float16 storage rounds at ~5e-4; another GPU's compiler at far less.
        assert relative_rmse(image, want, covered) < 2e-3, key
        assert np.array_equal(image[..., 3] > 0.5, covered), key
