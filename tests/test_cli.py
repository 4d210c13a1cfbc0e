"""Every a3d command shares one skeleton: --version, plain help with defaults, one exit-code mapping."""

from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
from importlib.metadata import entry_points, version

import pytest

from a3d.runtime.cli.common import EXIT_INTERRUPTED, EXIT_USAGE, command
from a3d.runtime.errors import InputError

COMMANDS = sorted(
    (ep.name, ep.value.split(":")[0])
    for ep in entry_points(group="console_scripts")
    if ep.name.startswith("a3d-")
)
RST = re.compile(r"``|:(func|class|mod|meth|ref):`")


def test_the_commands_are_installed() -> None:
    names = [name for name, _ in COMMANDS]
    expected = ["a3d-average", "a3d-eval", "a3d-export", "a3d-finetune", "a3d-labels", "a3d-nyuv2"]
    expected += ["a3d-poses", "a3d-pretrain"]
    expected += ["a3d-run", "a3d-sunrgbd", "a3d-synth", "a3d-train", "a3d-vgg16-weights", "a3d-world-boxes"]
    assert names == expected


@pytest.mark.parametrize(("name", "module"), COMMANDS)
def test_parser_help_is_plain_complete_and_shows_defaults(name: str, module: str) -> None:
    parser = importlib.import_module(module).build_parser()
    assert parser.prog == name
    text = parser.format_help()
    assert not RST.search(text), f"{name} --help has reST markup: {RST.search(text).group(0)!r}"
    formatter = parser.formatter_class(prog=name)
    for action in parser._actions:
        if not action.option_strings or isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            continue
        assert action.help and action.help.strip(), f"{name} {action.option_strings[0]} has no help"
        if not (
            action.default is None or action.default is False or action.default in ([], argparse.SUPPRESS)
        ):
            shown = formatter._expand_help(action)
            assert "default" in shown, f"{name} {action.option_strings[0]}: default not shown"


@pytest.mark.parametrize(("name", "module"), COMMANDS)
def test_version_and_usage_errors(name: str, module: str, capsys: pytest.CaptureFixture[str]) -> None:
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"a3d {version('a3d')}"
    with pytest.raises(SystemExit) as done:
        main(["--no-such-flag"])
    assert done.value.code == EXIT_USAGE


def test_version_from_the_console_script() -> None:
    command_line = [sys.executable, "-m", "a3d.runtime.cli.eval", "--version"]
    result = subprocess.run(command_line, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stdout.strip() == f"a3d {version('a3d')}"


def test_error_mapping(capsys: pytest.CaptureFixture[str]) -> None:
    @command("a3d-x", errors=(OSError,))
    def main(argv: list[str] | None = None) -> int:
        what = argv[0]
        if what == "input":
            raise InputError("frames/a.depth.png: depth is\n480x640")
        if what == "os":
            raise FileNotFoundError("out/: no such folder")
        if what == "ctrl-c":
            raise KeyboardInterrupt
        if what == "bug":
            raise RuntimeError("a bug is not a usage error")
        return int(what)

    assert main(["0"]) == 0 and main(["1"]) == 1
    assert main(["input"]) == EXIT_USAGE
    assert capsys.readouterr().err == "a3d-x: error: frames/a.depth.png: depth is; 480x640\n"
    assert main(["os"]) == EXIT_USAGE
    assert capsys.readouterr().err == "a3d-x: error: out/: no such folder\n"
    assert main(["ctrl-c"]) == EXIT_INTERRUPTED
    assert "a3d-x: interrupted" in capsys.readouterr().err
    with pytest.raises(RuntimeError):
        main(["bug"])


def test_synth_bad_input_exits_2_with_one_line(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    from a3d.synth.cli import main

    assert main(["--stats", str(tmp_path / "absent")]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(tmp_path / "absent") in err
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main([str(blocker / "set"), "--frames", "1"]) == EXIT_USAGE
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as done:
        main([str(tmp_path / "set"), "--frames", "0"])
    assert done.value.code == EXIT_USAGE


# A missing input of each command (relative to an empty folder): not a usage error, so one line
# "PROG: error: ..." naming it, without argparse's usage dump.
MISSING_INPUT = {
    "a3d-run": ["no/such/folder", "--headless"],
    "a3d-eval": ["no/such/folder", "--detections", "det.jsonl"],
    "a3d-synth": ["--stats", "no/such/folder"],
    "a3d-sunrgbd": ["no/such/folder", "out"],
    "a3d-nyuv2": ["no/such/folder", "out"],
    "a3d-train": ["no/such/folder", "--out", "run", "--config", "cpu-tiny"],
    "a3d-pretrain": ["no/such/folder", "--out", "w.pt", "--config", "cpu-tiny"],
    "a3d-average": ["no/such/a.pt", "no/such/b.pt", "--out", "soup.pt"],
    "a3d-export": ["no/such/folder/checkpoint.pt", "-o", "model.onnx"],
    "a3d-vgg16-weights": ["no/such/vgg16.h5", "--out", "vgg16.pt"],
    "a3d-labels": ["no/such/world_boxes.json", "no/such/folder", "--out", "out"],
    "a3d-poses": ["no/such/folder", "--out", "out"],
    "a3d-world-boxes": ["no/such/folder", "--rough", "rough.csv"],
    "a3d-finetune": ["no/such/folder", "--out", "model.onnx"],
}


@pytest.mark.parametrize(("name", "module"), COMMANDS)
def test_a_missing_input_is_one_line_without_the_usage(
    name: str, module: str, tmp_path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert importlib.import_module(module).main(MISSING_INPUT[name]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "usage:" not in err, err
    assert err.startswith(f"{name}: error: no/such/"), err
