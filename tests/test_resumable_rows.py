"""lftomo.io.ResumableRows: the rows a long study has finished survive an interruption and are reused."""

import json
import subprocess
import sys

import numpy as np
import pytest

from lftomo.io import ResumableRows

SETTINGS = {"n": 24, "draws": 3, "rule": "discrepancy"}


def test_rows_are_kept_and_reused(tmp_path):
    p = tmp_path / "draws.jsonl"
    rows = ResumableRows(p, SETTINGS)
    assert rows.get(0) is None
    rows.add(0, {"draw": 0, "err": np.float64(0.05), "n": np.int64(3)})
    rows.add("1-auto", {"draw": 1, "err": 0.07})
    again = ResumableRows(p, dict(SETTINGS))
    assert again.get(0) == {"draw": 0, "err": 0.05, "n": 3}
    assert again.get("1-auto") == {"draw": 1, "err": 0.07}
    assert again.get(2) is None


def test_a_cut_last_line_is_computed_again(tmp_path):
    p = tmp_path / "draws.jsonl"
    rows = ResumableRows(p, SETTINGS)
    rows.add(0, {"err": 1.0})
    with open(p, "a", encoding="utf-8") as fh:  # what a kill in the middle of a write leaves
        fh.write('{"key": "1", "row": {"err": 2.')
    again = ResumableRows(p, SETTINGS)
    assert again.get(0) == {"err": 1.0} and again.get(1) is None
    again.add(1, {"err": 2.0})  # appended after a clean line, not glued to the cut one
    assert ResumableRows(p, SETTINGS).get(1) == {"err": 2.0}
    assert all(json.loads(line) for line in p.read_text().splitlines())


def test_other_settings_start_afresh_and_keep_the_old_rows_aside(tmp_path):
    p = tmp_path / "draws.jsonl"
    ResumableRows(p, SETTINGS).add(0, {"err": 1.0})
    other = ResumableRows(p, {**SETTINGS, "rule": "gcv"})
    assert other.get(0) is None
    assert (tmp_path / "draws.jsonl.old").is_file()


def test_a_killed_writer_loses_at_most_the_row_in_progress(tmp_path):
    """A process killed (SIGKILL) while it adds rows: every row it finished is read back."""
    p = tmp_path / "draws.jsonl"
    code = ("import sys, time\nfrom lftomo.io import ResumableRows\n"
            f"r = ResumableRows({str(p)!r}, {SETTINGS!r})\n"
            "for k in range(10**6):\n    r.add(k, {'k': k, 'pad': 'x' * 500})\n    print(k, flush=True)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    done = [int(proc.stdout.readline()) for _ in range(30)]
    proc.kill()
    proc.wait()
    rows = ResumableRows(p, SETTINGS)
    assert all(rows.get(k) == {"k": k, "pad": "x" * 500} for k in done)


def test_the_rows_file_location_is_checked(tmp_path):
    with pytest.raises(ValueError, match="rows file"):
        ResumableRows(tmp_path / "missing" / "x.jsonl", SETTINGS)
