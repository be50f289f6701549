import subprocess
import sys

from hydrowatch.cli import build_parser, main


def test_help_lists_commands_and_exits_cleanly():
    out = subprocess.run([sys.executable, "-m", "hydrowatch", "--help"], capture_output=True, text=True)
    assert out.returncode == 0
    assert "hydrowatch" in out.stdout


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_every_command_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, p in sub.choices.items():  # type: ignore[union-attr]
        assert p.description, name
