"""The command line: help, one-line errors, --debug tracebacks."""

import subprocess
import sys

import pytest

from cobotlab import cli


def test_help_lists_the_commands(capsys):
    with pytest.raises(SystemExit) as excinfo:
        cli.main(["--help"])
    assert excinfo.value.code == 0
    assert "demo" in capsys.readouterr().out


def test_errors_are_one_line_without_debug(capsys):
    assert cli.main(["demo", "--poses", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("cobotlab: error:") and "n_poses" in err
    assert "Traceback" not in err and len(err.splitlines()) == 1


def test_debug_shows_the_exception():
    with pytest.raises(ValueError, match="n_poses"):
        cli.main(["--debug", "demo", "--poses", "2"])


def test_console_script_runs_the_demo():
    out = subprocess.run([sys.executable, "-m", "cobotlab.cli", "demo", "--poses", "6"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for expected in ("eye_in_hand", "eye_to_hand", "nonlinear", "opencv PARK"):
        assert expected in out.stdout
    assert "failed" not in out.stdout


def test_robot_check_reads_the_cell_and_moves_nothing(capsys):
    assert cli.main(["robot", "check", "--arm", "ur5e"]) == 0
    out = capsys.readouterr().out
    assert "connected: sim / ur5e" in out
    assert "flange (mm)" in out and "safety: workspace" in out
    assert out.rstrip().endswith("nothing moved.")


def test_robot_check_unknown_kind_is_one_line(capsys):
    assert cli.main(["robot", "check", "--kind", "kuka"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown robot kind 'kuka'" in err and len(err.splitlines()) == 1


def test_robot_check_jog_moves_only_after_a_yes(monkeypatch, capsys):
    answers = iter(["x+", "y", "z-", "n", "q"])
    monkeypatch.setattr("builtins.input", lambda prompt="": next(answers))
    assert cli.main(["robot", "check", "--arm", "ur5e", "--jog"]) == 0
    out = capsys.readouterr().out
    assert "moved." in out and "you answered no" in out
    assert out.rstrip().endswith("1 jog move(s) made.")
