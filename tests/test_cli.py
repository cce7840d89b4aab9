"""The ``seesys`` command line: one group per part, help for each, one-line errors."""

import subprocess
import sys

import pytest

from seesys_app import cli

# The commands a user finds in `seesys --help`, and the part that provides each.
EXPECTED_COMMANDS = {
    "track": "slam_monitor",
    "vocab": "slam_monitor",
    "monitor": "slam_monitor",
    "synth": "synth",
    "dataset": "estimator",
    "estimator": "estimator",
    "advisory": "advisory",
    "study": "study",
    "analyze": "analysis",
}
# Commands a part above adds to a lower part's group, and the part that provides each: the diversity report reads
# rendered frames through the device's image statistics, which the renderer never imports; the simulated study runs
# the estimator in-process, which the study part never imports (their import contracts).
EXTENSIONS = {
    ("synth", "diversity"): "estimator",
    ("study", "simulate"): "seesys_app",
    ("study", "simulate-session"): "seesys_app",
}


def _commands() -> dict[str, object]:
    parser = cli.build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return action.choices


def _leaf_functions(parser) -> list:
    """The functions a command runs: its own, or those of its subcommands, at any depth."""
    handler = parser.get_default("func")
    if handler is not None:
        return [handler]
    groups = [a for a in parser._actions if isinstance(a.choices, dict)]
    return [f for a in groups for sub in a.choices.values() for f in _leaf_functions(sub)]


def _subcommands(parser) -> dict[str, object]:
    return next(a for a in parser._actions if isinstance(a.choices, dict)).choices


def test_every_part_registers_its_commands():
    commands = _commands()
    assert set(EXPECTED_COMMANDS) <= set(commands)
    for name, part in EXPECTED_COMMANDS.items():
        subcommands = _subcommands(commands[name]) if commands[name].get_default("func") is None else {}
        own = [f for sub, p in subcommands.items() if (name, sub) not in EXTENSIONS for f in _leaf_functions(p)]
        funcs = own or _leaf_functions(commands[name])
        assert funcs and all(f.__module__.split(".")[0] == part for f in funcs), (name, funcs)
    for (group, name), part in EXTENSIONS.items():
        assert _subcommands(commands[group])[name].get_default("func").__module__.split(".")[0] == part


def _shape(parser) -> object:
    """A parser's commands and options, at any depth: what two parsers of the same command line must share."""
    options = sorted(a.dest for a in parser._actions if not isinstance(a.choices, dict))
    groups = {
        name: _shape(sub) for a in parser._actions if isinstance(a.choices, dict) for name, sub in a.choices.items()
    }
    return options, groups


def test_a_command_line_that_names_a_group_builds_that_group_alone_and_the_same_as_the_whole_parser():
    whole = _commands()
    assert set(cli.COMMAND_GROUPS) == set(whole)  # every group is mapped to the part that makes it, and only those
    for name in cli.COMMAND_GROUPS:
        commands = next(a for a in cli.build_parser(name)._actions if a.dest == "command").choices
        assert name in commands and set(commands) <= {
            g for g, part in cli.COMMAND_GROUPS.items() if part == cli.COMMAND_GROUPS[name]
        }
        assert _shape(commands[name]) == _shape(whole[name]), name


@pytest.mark.system
def test_an_advisory_command_starts_without_the_estimators_dataset_code_or_plotting():
    probe = "import sys; from seesys_app import cli; cli.build_parser('advisory'); print(' '.join(sorted(sys.modules)))"
    loaded = set(
        subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split()
    )
    assert "advisory.cli" in loaded
    assert not {"estimator.dataset.build", "matplotlib.pyplot", "slam_monitor.cli", "torch"} & loaded


@pytest.mark.system
def test_help_lists_every_command_in_a_subprocess():
    out = subprocess.run([sys.executable, "-m", "seesys", "--help"], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("usage: seesys")
    # argparse lists each command indented by 4, a long name's help wrapped onto the next, deeper line
    listed = {line.split()[0] for line in out.stdout.splitlines() if line.startswith("    ") and line[4] != " "}
    assert listed == set(_commands())


@pytest.mark.parametrize("name", sorted(EXPECTED_COMMANDS))
def test_each_command_has_help(name, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main([name, "--help"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: seesys {name}")


@pytest.mark.system
def test_a_user_error_is_one_line_with_status_2(tmp_path):
    missing = tmp_path / "nope"
    out = subprocess.run(
        [sys.executable, "-m", "seesys", "track", "--source", f"tum:{missing}", "--out", str(tmp_path / "s")],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and out.stderr.startswith("seesys: error: ")
    assert str(missing) in out.stderr


@pytest.mark.system
def test_an_unknown_command_is_a_usage_error():
    out = subprocess.run([sys.executable, "-m", "seesys", "frobnicate"], capture_output=True, text=True)
    assert out.returncode == 2 and "invalid choice: 'frobnicate'" in out.stderr


@pytest.mark.parametrize(
    "flags, pace, wait_for_mapping",
    [
        ([], None, None),  # slam.toml decides
        (["--pace"], True, None),  # at camera rate, waiting for mapping where slam.toml says so (offline runs)
        (["--no-pace"], False, None),
        (["--real-time"], True, False),  # as a live camera: camera rate, never waiting for mapping
    ],
)
def test_pacing_flags_of_a_device_session(flags, pace, wait_for_mapping, tmp_path):
    from slam_monitor.tracking_commands import session_options_from_args

    args = cli.build_parser().parse_args(
        ["monitor", "run", "--source", "tum:data/sample", "--out", str(tmp_path), *flags]
    )
    options = session_options_from_args(args)
    assert (options.pace, options.wait_for_mapping) == (pace, wait_for_mapping)


def test_pacing_flags_exclude_each_other(capsys):
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["track", "--source", "tum:x", "--out", "y", "--pace", "--real-time"])
    assert "not allowed with argument" in capsys.readouterr().err
