"""The `stiction` shell: help, simulate, error handling, and every command documented."""

import re
from pathlib import Path

import numpy as np
import pytest

from connectors.historian import read_wide
from diagnose.service.cli import COMMANDS, main
from diagnose.stiction_model import simulate_valve

ROOT = Path(__file__).resolve().parents[1]


def test_help_lists_every_command(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert re.search(rf"^\s+{name}\s", out, re.M), name


def test_every_command_is_documented_in_the_readme():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for name in COMMANDS:
        assert f"stiction {name}" in readme, f"README does not document `stiction {name}`"


def test_every_command_module_exists():
    import importlib

    for name, (module, _) in COMMANDS.items():
        mod = importlib.import_module(f"diagnose.service.commands.{module}")
        assert callable(mod.add_arguments) and callable(mod.run), name


def test_simulate_writes_a_loop_with_the_true_mv(tmp_path, capsys):
    out = tmp_path / "loop.csv"
    rc = main(["simulate", "--S", "3", "--J", "1", "--n", "800", "--seed", "5", "--name", "FIC9",
               "--out", str(out)])
    assert rc == 0
    rec = read_wide(out)
    assert rec.name == "FIC9" and rec.n == 800 and rec.ts_s == pytest.approx(1.0)
    assert rec.mv is not None and rec.sp is not None
    # MV in the file is the valve model driven by the file's OP (6 significant digits in the file)
    assert np.abs(rec.mv - simulate_valve(rec.op, 3.0, 1.0, 1)).max() < 0.2
    assert "wrote" in capsys.readouterr().err


def test_usage_and_domain_errors_exit_without_traceback(tmp_path, capsys):
    assert main(["simulate", "--S", "3"]) == 2                       # missing --J and --out
    assert main(["simulate", "--S", "-1", "--J", "1", "--out", str(tmp_path / "x.csv")]) == 1
    err = capsys.readouterr().err
    assert "error: --S and --J must be >= 0" in err
    assert "Traceback" not in err
    assert main(["no-such-command"]) == 2
