"""The tuned TOML keeps the input's text, carries the new gains and loads back; the input
is never overwritten; the tables render every gain set."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.config import load_bench
from sim.tuning import linear, report
from sim.tuning.cost import TERMS
from sim.tuning.gains import GainSet

BENCH = Path(__file__).resolve().parents[3] / "bench_configs" / "paper_bench.toml"


def _tuned(bench) -> GainSet:
    g = GainSet.from_bench(bench)
    return g.replace(kp_v_a_per_dps=0.1234567, kp_p_per_s=42.5, ki_i_v_per_as=250.0)


def test_tuned_toml_loads_back_with_the_new_gains(bench, tmp_path):
    gains = _tuned(bench)
    out = report.write_tuned_toml(BENCH, tmp_path / "tuned.toml", gains, "tuned (test)")
    again = load_bench(out)
    assert GainSet.from_bench(again) == GainSet(
        **{k: float(f"{v:.6g}") for k, v in gains.as_dict().items()}
    )
    # Everything else is the same bench.
    assert again.plant == bench.plant
    assert again.firmware.limits == bench.firmware.limits
    text = out.read_text()
    assert "# The servo turntable of Du et al. 2022" in text
    # the value replaced, the comment in the config's column, every other line as it was
    assert "kp_a_per_dps = 0.123457         # tuned (test)\n" in text
    assert text.count("tuned (test)") == 5
    source = BENCH.read_text().splitlines()
    written = text.splitlines()
    assert len(written) == len(source)
    changed = [k for k, (a, b) in enumerate(zip(source, written, strict=True)) if a != b]
    assert len(changed) == 5
    for k in changed:
        assert written[k].index("#") == source[k].index("#")


def test_missing_keys_and_tables_are_added():
    gains = GainSet(0.2, 100.0, 0.05, 1.0, 10.0)
    source = "# my bench\n[controller.velocity]  # the speed loop\nacc_ff_a_per_dps2 = 0.001\n"
    text = report.tuned_toml_text(source, gains, "n")
    assert text.startswith(source)  # what was there stays, first
    assert "kp_a_per_dps = 0.05  # n\nki_a_per_deg = 1.0  # n\n" in text
    assert "[controller.current]\nkp_v_per_a = 0.2  # n\nki_v_per_as = 100.0  # n" in text
    assert "[controller.position]\nkp_per_s = 10.0  # n" in text
    import tomllib

    tables = tomllib.loads(text)["controller"]
    assert tables["velocity"] == {
        "acc_ff_a_per_dps2": 0.001,
        "kp_a_per_dps": 0.05,
        "ki_a_per_deg": 1.0,
    }


def test_a_config_that_is_not_toml_is_a_value_error():
    with pytest.raises(ValueError, match="not valid TOML"):
        report.tuned_toml_text("[controller\n", GainSet(0.2, 100.0, 0.05, 1.0, 10.0), "n")


def test_the_input_is_never_overwritten(bench, tmp_path):
    src = tmp_path / "bench.toml"
    src.write_text(BENCH.read_text())
    with pytest.raises(ValueError, match="would overwrite the input"):
        report.write_tuned_toml(src, src, _tuned(bench), "x")
    assert src.read_text() == BENCH.read_text()


def test_tables_list_every_set_and_term(bench):
    gains = {"config": GainSet.from_bench(bench), "tuned": _tuned(bench)}
    terms = {k: {t: 0.5 for t in TERMS} for k in gains}
    table = report.terms_table(terms, {"config": 2.0, "tuned": 1.0})
    assert table.splitlines()[0] == "| gains | " + " | ".join(TERMS) + " | cost |"
    assert len(table.splitlines()) == 4
    margins = {k: linear.analyse(bench, g) for k, g in gains.items()}
    assert len(report.margins_table(margins).splitlines()) == 2 + 6
