"""The command line: help, exit codes, `info`."""

from __future__ import annotations

import subprocess
import sys

import pytest

from rtdefocus import cli


def test_help_shows_examples(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out and "rtdefocus calibrate" in out


def test_no_command_is_usage_error(capsys):
    assert cli.main([]) == 2


def test_bad_size_is_usage_error():
    with pytest.raises(Exception, match="WIDTHxHEIGHT"):
        cli.parse_size("800by600")
    assert cli.parse_size("800x600") == (800, 600)


def test_info_lists_opencl_and_gl():
    res = subprocess.run([sys.executable, "-m", "rtdefocus", "info"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "OpenCL:" in res.stdout and "OpenGL" in res.stdout
    from rtdefocus.cl.runtime import opencl_available
    ok, desc = opencl_available()
    if ok:
        assert "compute units" in res.stdout


def test_library_error_exits_1_with_message(tmp_path, capsys):
    from rtdefocus.errors import RtDefocusError

    def boom(args):
        raise RtDefocusError("the reason and the fix")
    parser_main = cli.main
    cli.COMMANDS.append(lambda sub: sub.add_parser("boom").set_defaults(func=boom))
    try:
        assert parser_main(["boom"]) == 1
    finally:
        cli.COMMANDS.pop()
    assert "the reason and the fix" in capsys.readouterr().err
