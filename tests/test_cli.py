import subprocess
import sys

from hydrowatch.cli import build_parser, command_modules, main


def test_help_lists_every_command_without_importing_them():
    code = (
        "import sys; from hydrowatch.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "print('torch' in sys.modules, 'mlflow' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    for name in command_modules():
        assert name in out.stdout
    assert out.stdout.strip().endswith("False False")


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_every_command_has_help_and_a_name_matching_its_module():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "subcommand")
    assert set(sub.choices) == set(command_modules())  # type: ignore[arg-type]
    for name, p in sub.choices.items():  # type: ignore[union-attr]
        assert p.description, name


def test_only_the_chosen_command_is_built():
    parser = build_parser(["-v", "info", "x.mcap"])
    args = parser.parse_args(["-v", "info", "x.mcap"])
    assert args.subcommand == "info" and args.verbose == 1 and callable(args._run)
