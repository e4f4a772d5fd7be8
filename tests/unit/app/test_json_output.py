"""``--json``: stdout carries one strict JSON document and nothing else (``scenenav.app.json_output``)."""

import json
import math
import os
import subprocess
import sys

import numpy as np

from scenenav.app.json_output import emit_json, json_only_stdout, strict


def test_inside_json_only_stdout_everything_else_goes_to_stderr(capfd):
    with json_only_stdout():
        print("a table line")
        os.write(1, b"a library banner written to fd 1\n")
        subprocess.run([sys.executable, "-c", "print('a child process')"], check=True)
        emit_json({"real_time_factor": 2.5})
    out, err = capfd.readouterr()
    assert json.loads(out) == {"real_time_factor": 2.5}
    assert "a table line" in err and "library banner" in err and "a child process" in err
    print("after")                                  # stdout is restored
    assert capfd.readouterr().out == "after\n"


def test_strict_json_has_no_nan_and_takes_numpy_values(capfd):
    emit_json({"a": math.nan, "b": [math.inf, 1.0], "c": np.float64(2.0), "d": np.int64(3),
               "e": np.arange(2), "f": (1, 2)})
    out = capfd.readouterr().out
    assert "NaN" not in out and "Infinity" not in out
    assert json.loads(out) == {"a": None, "b": [None, 1.0], "c": 2.0, "d": 3, "e": [0, 1], "f": [1, 2]}
    assert strict({"x": {"y": -math.inf}}) == {"x": {"y": None}}


def test_a_bad_value_with_json_is_one_error_line_and_an_empty_stdout():
    r = subprocess.run([sys.executable, "-m", "scenenav.app.cli", "bench", "sim", "--json",
                        "--sizes", "12xfoo"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    assert [ln for ln in r.stderr.splitlines() if ln.strip()][-1].startswith("error: ")
