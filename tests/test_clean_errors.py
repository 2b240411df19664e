"""Issue 30, item 5: every input or option that used to give a traceback, a hang or a
misleading line gives a clean one-line error (naming the file or option, the place and the
problem), quickly. Each case here is small: the bundled reference recording changed as a
user or tracker would change it, synthetic files, or argument parsing only."""

import os

import pytest

from fitlug.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REF = os.path.join(ROOT, "data", "reference", "trajectories.csv")


def _one_error_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    assert "Traceback" not in err[0] and "Warning" not in err[0], err
    return err[0]


def _refused_at_parsing(argv, capsys) -> str:
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if "error:" in ln]
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("argv,words", [
    (["--seed", "-1"], ("--seed", "-1", "0 .. 4294967295")),
    (["--seed", "99999999999999999999999"], ("--seed", "out of range")),
    (["--seed", "1.5"], ("--seed", "not an integer")),
    (["--mcmc-budget", "0"], ("--mcmc-budget", "> 0")),
    (["--mcmc-budget", "nan"], ("--mcmc-budget", "finite")),
    (["--mcmc-budget=-inf"], ("--mcmc-budget", "finite")),
    (["--mcmc-budget", "abc"], ("--mcmc-budget", "not a number")),
])
def test_bad_seed_and_budget_refused_before_any_fit(argv, words, capsys, tmp_path):
    out = tmp_path / "fit"
    line = _refused_at_parsing([REF, "--out", str(out)] + argv, capsys)
    for w in words:
        assert w in line, line
    assert not out.exists()  # refused before any work


def test_campaign_and_simulate_refuse_bad_seed(capsys):
    assert "--seed" in _refused_at_parsing(["campaign", REF, "--seed", "-1"], capsys)
    assert "--mcmc-budget" in _refused_at_parsing(["campaign", REF, "--mcmc-budget", "0"], capsys)
    assert "--seed" in _refused_at_parsing(["simulate", "--seed", "2e40"], capsys)


def test_largest_seed_accepted():
    from fitlug.cli._common import SEED_MAX, seed_arg

    assert seed_arg(str(SEED_MAX)) == SEED_MAX == 2 ** 32 - 1
    import numpy as np

    np.random.default_rng(SEED_MAX)  # the range documented is one numpy takes
    np.random.RandomState(SEED_MAX)  # and emcee's legacy generator


def _state_bytes() -> bytes:
    import io
    import json

    import numpy as np

    buf = io.BytesIO()
    rng = np.random.default_rng(1)
    np.savez_compressed(buf, meta=np.array(json.dumps({"run_id": "x"})),
                        t=rng.normal(size=20000), y=rng.normal(size=20000))
    return buf.getvalue()


@pytest.mark.parametrize("damage", ["truncated", "cut_short", "bit_flips", "empty", "text"])
def test_report_on_a_damaged_state_file_is_one_line(damage, tmp_path, capsys):
    good = _state_bytes()
    data = {"truncated": good[: len(good) // 2], "cut_short": good[:-30], "empty": b"",
            "text": b"not a zip file\n"}.get(damage)
    if damage == "bit_flips":
        b = bytearray(good)
        for i in range(200, len(b) - 200, 997):
            b[i] ^= 0xFF
        data = bytes(b)
    (tmp_path / "fit.json").write_text('{"run_id": "x"}')
    (tmp_path / "state.npz").write_bytes(data)
    assert main(["report", str(tmp_path)]) == 2
    line = _one_error_line(capsys)
    assert "state.npz" in line and "truncated or damaged" in line, line
    assert not (tmp_path / "report.html").exists()
