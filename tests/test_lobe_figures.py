"""The filter-quality report (Figs. 4 and 5 analogues of Knuth et al. 2014, section 5)."""

from __future__ import annotations

import json
import math

import pytest
from PIL import Image

from garment_lab.lobe_figures import DEFAULT_S_VALUES, write_lobe_report
from renderer.errors import InvalidInputError
from renderer.lighting.filters import Filter

FACE = 32


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("lobes")
    return out, write_lobe_report(out, face_size=FACE)


def test_files_exist_and_pngs_are_images(report):
    out, _ = report
    for name in ("lobes_fig4.png", "lobes_fig5.png", "lobes.md", "lobes.json"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    for name in ("lobes_fig4.png", "lobes_fig5.png"):
        with Image.open(out / name) as im:
            im.verify()
        with Image.open(out / name) as im:
            assert im.format == "PNG"
            assert im.size[0] > 100 and im.size[1] > 100


def test_json_matches_return_value_and_has_all_filters(report):
    out, data = report
    assert json.loads((out / "lobes.json").read_text()) == data
    assert data["face_size"] == FACE
    assert set(data["filters"]) == {f.value for f in Filter}
    assert data["s_values"] == sorted(float(s) for s in DEFAULT_S_VALUES)
    assert "4 %" in data["paper_comparison"]
    md = (out / "lobes.md").read_text()
    for f in Filter:
        assert f"| {f.value} |" in md


def test_levels_grow_as_s_decreases(report):
    _, data = report
    for name, r in data["filters"].items():
        levels = r["levels"]  # ordered by increasing s
        assert len(levels) == len(data["s_values"])
        assert all(a >= b for a, b in zip(levels, levels[1:])), (name, levels)
        assert 0.0 <= min(levels) and max(levels) <= data["n_levels"] - 1
        assert r["diffuse_level"] == pytest.approx(levels[0])


def test_errors_finite(report):
    _, data = report
    for name, r in data["filters"].items():
        values = r["errors_pct"] + r["curve"]["errors_pct"] + [r["mean_error_pct"], r["max_error_pct"],
                                                               r["diffuse_error_pct"], r["diffuse_level"]]
        assert all(math.isfinite(v) and v >= 0.0 for v in values), name
        assert r["max_error_pct"] == pytest.approx(max(r["errors_pct"]))


def test_filtering_improves_the_diffuse_lobe(report):
    # The paper's main point of section 5: the low-pass filters give a better diffuse lobe than plain MIP.
    _, data = report
    f = data["filters"]
    assert f["sqrt-cosine"]["diffuse_error_pct"] < f["none"]["diffuse_error_pct"]


def test_subset_and_bad_input(tmp_path):
    data = write_lobe_report(tmp_path, face_size=8, filters=["box"], s_values=[4, 1])
    assert list(data["filters"]) == ["box"] and data["s_values"] == [1.0, 4.0]
    with pytest.raises(InvalidInputError):
        write_lobe_report(tmp_path, face_size=8, filters=["bogus"])
    with pytest.raises(InvalidInputError):
        write_lobe_report(tmp_path, face_size=8, s_values=[0.5])
