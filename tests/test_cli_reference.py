"""The command line's help: the common flags on one screen, every flag in the generated docs/cli.md."""

import subprocess
import sys
from pathlib import Path

import pytest

from renderer.cli import COMMON_FLAGS, build_parser, cli_reference
from renderer.config import RETIRED

ROOT = Path(__file__).resolve().parents[1]


def test_the_stored_reference_is_what_the_parser_generates():
    stored = (ROOT / "docs" / "cli.md").read_text()
    assert stored == cli_reference() + "\n", "docs/cli.md is stale: regenerate it with renderer.cli.cli_reference()"


def test_help_lists_the_common_flags_and_help_all_every_one():
    def run(flag):
        return subprocess.run([sys.executable, "-m", "renderer.cli", "render", flag], capture_output=True, text=True,
                              check=True, cwd=ROOT).stdout

    short, full = run("--help"), run("--help-all")
    assert len(short.splitlines()) <= 70 < len(full.splitlines())
    for flag in ("--env", "--mesh", "--preset", "--lights", "--size", "--out", "--exr", "--timings", "--background"):
        assert flag in short
    assert "--caster-detail" in full and "--caster-detail" not in short
    assert "--sub-lights" in full and "--sub-lights" not in short


def test_every_shown_flag_is_an_option_of_the_parser_and_a_hidden_one_still_parses():
    p = build_parser(show_all=False)
    args = p.parse_args(["render", "--caster-detail", "0.5", "--lights", "24"])
    assert args.caster_detail == 0.5 and args.lights == 24
    options = {o for a in build_parser()._subparsers._group_actions[0].choices["render"]._actions
               for o in a.option_strings}
    assert COMMON_FLAGS - {"--frames", "--topology", "--body", "--spp", "--seed"} <= options


@pytest.mark.parametrize("name", sorted(RETIRED))
def test_a_retired_flag_is_refused_with_what_replaced_it(name, capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["render", f"--{name.replace('_', '-')}"])
    assert "removed" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["render", "reference"])
def test_a_render_that_would_write_nothing_or_into_no_folder_is_refused_before_the_work(tmp_path, capsys, command):
    from renderer import cli

    assert cli.main([command, "--size", "16x16"]) == 2
    assert "would write nothing: name --out" in capsys.readouterr().err
    missing = tmp_path / "no-such-folder" / "frame.png"
    assert cli.main([command, "--size", "16x16", "--out", str(missing)]) == 2
    assert f"the folder {missing.parent} does not exist" in capsys.readouterr().err
    assert not missing.parent.exists()


def test_meshes_in_other_units_or_lying_down_are_warned_of_and_take_a_scale_and_an_up_each(tmp_path, capsys):
    """A garment in centimetres beside a body in metres, and a Z-up pair read as Y-up: the render says
    so (before it starts); per-mesh --mesh-scale and --up fix both, and the warnings go."""
    import trimesh

    from renderer import cli

    body = trimesh.creation.cylinder(radius=0.15, height=1.7)   # Z-up: its height along Z
    garment = trimesh.creation.cylinder(radius=20.0, height=60.0)   # centimetres, Z-up too
    body.apply_translation((0, 0, 0.85))
    garment.apply_translation((0, 0, 120.0))
    paths = [tmp_path / "garment.obj", tmp_path / "body.obj"]
    garment.export(paths[0])
    body.export(paths[1])
    meshes = [arg for p in paths for arg in ("--mesh", str(p))]
    common = ["render", "--size", "24x24", "--preset", "fast", "--lights", "6", "--face-size", "16",
              "--timings", str(tmp_path / "t.json")]
    assert cli.main(common + meshes) == 0
    err = capsys.readouterr().err
    assert "times the size of" in err and "--mesh-scale 0.01,1" in err
    assert "Z-up file read as Y-up" in err
    assert cli.main(common + meshes + ["--mesh-scale", "0.01,1", "--up", "z"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert cli.main(common + meshes + ["--mesh-scale", "0.01,1,1"]) == 2
    assert "--mesh-scale gives 3 values for 2 meshes" in capsys.readouterr().err


def test_an_install_without_the_lab_names_it_for_each_of_its_commands(monkeypatch, capsys):
    """The lab's commands come from its entry point (renderer/cli.py, lab_commands); without the lab
    each is still a command, which answers with the line that installs it."""
    import importlib.metadata

    from renderer import cli

    real = importlib.metadata.entry_points
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda **kw: [] if kw.get("group") == cli.LAB_ENTRY_POINTS else real(**kw))
    for name in cli.LAB_COMMANDS:
        assert cli.main([name, "--broad"]) == 2
        err = capsys.readouterr().err
        assert f"{name} is one of the lab's commands" in err and "pip install ./lab" in err, err
    monkeypatch.undo()
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    assert sub.choices["bench"].get_default("func").__module__ == "garment_lab.cli"   # installed here: the lab's own
