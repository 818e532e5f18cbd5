"""gonio.cli.main builds its parser once per process (``_parser``) and every ``main`` call parses with it: a call
sees only its own arguments — values and defaults of the calls before it never carry over — and prints and exits
as a fresh parser does."""

from __future__ import annotations

import pytest

from gonio.cli.main import _parser, build_parser, main


def test_every_call_parses_with_one_parser_and_sees_only_its_own_arguments(capsys):
    assert _parser() is _parser()
    assert main(["models", "--eval", "phong", "--param", "kd=0.5"]) == 0
    first = capsys.readouterr().out
    assert main(["models", "--eval", "phong"]) == 0  # --param's list from the call before is not carried over
    default = capsys.readouterr().out
    assert main(["models", "--eval", "phong", "--param", "kd=0.5"]) == 0
    assert capsys.readouterr().out == first != default
    ns = _parser().parse_args(["models"])
    assert ns.param == [] and ns.eval is None and ns.theta_i == 30.0
    assert vars(ns).keys() == vars(build_parser().parse_args(["models"])).keys()


def test_errors_are_the_fresh_parser_s(capsys):
    for _ in range(2):
        with pytest.raises(SystemExit) as e:
            main(["models", "--theta-i", "x"])
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert "usage: gonio models" in err and "--theta-i: invalid float value: 'x'" in err
    with pytest.raises(SystemExit):
        build_parser().parse_args(["models", "--theta-i", "x"])
    assert capsys.readouterr().err == err
