"""sim.config: every validation path names the file, the table, the key and the value."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from serial_protocol.exceptions import ConfigError
from serial_protocol.messages import Loop, Move, Profile, SetGains
from sim import params as sim_params
from sim.config import load_bench, load_experiment

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
LARGEST_FRAME, LARGEST_NAME = sim_params.largest_board_frame()


def _write(tmp_path: Path, name: str, text: str) -> Path:
    f = tmp_path / name
    f.write_text(text)
    return f


def _bench_with(tmp_path: Path, extra: str) -> Path:
    return _write(tmp_path, "bench.toml", BENCH.read_text() + "\n" + extra)


def _expect(path_or_call, *parts: str):
    with pytest.raises(ConfigError) as info:
        path_or_call()
    text = str(info.value)
    for part in parts:
        assert part in text, f"{part!r} not in {text!r}"
    return text


def test_paper_bench_loads_with_the_agreed_numbers():
    b = load_bench(BENCH)
    assert b.plant.total_ratio == 400
    assert b.plant.bridge.arr == 3600
    assert b.plant.encoder.counts_per_rev == 16384
    assert b.dt_s == 0.002
    assert b.firmware.limits.current_limit_a == 5.0


# (table, key, bad value as TOML, fragment of the reason) for every check of sim/params.py
PLANT_BAD = [
    ("supply", "voltage_v", "-24.0", "> 0"),
    ("supply", "voltage_v", "30.0", "over-voltage"),
    ("bridge", "r_on_path_ohm", "-0.1", ">= 0"),
    ("bridge", "timer_clock_hz", "0.0", "> 0"),
    ("bridge", "pwm_hz", "5e7", "timer steps"),
    ("bridge", "current_limit_a", "0.0", "> 0"),
    ("bridge", "diode_drop_v", "nan", "finite"),
    ("current_sense", "k_ilis", "-1.0", "> 0"),
    ("current_sense", "r_is_ohm", "0.0", "> 0"),
    ("current_sense", "adc_vref_v", "inf", "finite"),
    ("current_sense", "adc_bits", "3", "integer in [6, 16]"),
    ("current_sense", "noise_rms_lsb", "-1.0", ">= 0"),
    ("motor", "r_ohm", "0.0", "> 0"),
    ("motor", "l_h", "-1e-3", "> 0"),
    ("motor", "kt_nm_a", "0.0", "> 0"),
    ("motor", "ke_v_s_rad", "-0.01", "> 0"),
    ("motor", "j_kgm2", "0.0", "> 0"),
    ("motor", "viscous_nm_s_rad", "-1.0", ">= 0"),
    ("motor", "coulomb_nm", "-0.1", ">= 0"),
    ("motor", "coulomb_band_rad_s", "0.0", "> 0"),
    ("gearbox", "ratio", "0.0", "> 0"),
    ("gearbox", "efficiency", "1.5", "(0, 1]"),
    ("gearbox", "backlash_deg", "-0.5", ">= 0"),
    ("belt", "small_teeth", "4", "integer >= 8"),
    ("belt", "large_teeth", "85.5", "must be an integer"),
    ("belt", "stiffness_nm_rad", "0.0", "> 0"),
    ("belt", "damping_nm_s_rad", "-2.0", ">= 0"),
    ("platter", "j_kgm2", "0.0", "> 0"),
    ("platter", "coulomb_nm", "-0.3", ">= 0"),
    ("platter", "viscous_nm_s_rad", "-0.05", ">= 0"),
    ("platter", "coulomb_band_rad_s", "-1e-3", "> 0"),
    ("encoder", "bits", "30", "integer in [8, 20]"),
    ("encoder", "latency_s", "0.5", "< 0.01"),
    ("encoder", "noise_rms_lsb", "-1.0", ">= 0"),
    ("encoder", "offset_counts", "-3.0", ">= 0"),
    ("uart", "fifo_bytes", "8", "largest frame the board sends ("),
    ("uart", "fifo_bytes", str(LARGEST_FRAME - 1), f"integer in [{LARGEST_FRAME},"),
    ("uart", "bit_flip_rate", "1.5", "probability"),
    ("uart", "burst_rate", "0.9\ndrop_rate = 0.5", "add up"),
    ("uart", "burst_bytes", "0", "integer in [1, 1048576]"),
    ("loop", "event_levels", "99", "integer in [0, 40]"),
]


@pytest.mark.parametrize(("table", "key", "value", "reason"), PLANT_BAD)
def test_every_plant_check_names_file_table_key_value(tmp_path, table, key, value, reason):
    text = BENCH.read_text()
    # Replace the key in its table (or add the table) so that the bad value is the only one.
    pattern = re.compile(rf"(^\[{table}\]\n(?:(?!^\[).*\n)*?){key} = [^\n]*\n", re.M)
    if pattern.search(text):
        text = pattern.sub(lambda m: m.group(1), text, count=1)
    text = text.replace(f"[{table}]\n", f"[{table}]\n{key} = {value}\n", 1)
    if f"[{table}]\n" not in text:
        text += f"\n[{table}]\n{key} = {value}\n"
    f = _write(tmp_path, "bench.toml", text)
    shown = value.split("\n")[0]
    _expect(lambda: load_bench(f), str(f), f"[{table}]", key, reason)
    assert reason and shown


def test_every_plant_dataclass_rejects_its_bad_values_directly():
    # The dataclasses check themselves too (no TOML needed): one bad value per class.
    with pytest.raises(ValueError, match=r"r_ohm = -1"):
        sim_params.MotorParams(r_ohm=-1.0)
    with pytest.raises(ValueError, match="efficiency"):
        sim_params.GearboxParams(efficiency=np.array([0.8, 1.2]))


def test_file_errors(tmp_path):
    _expect(lambda: load_bench(tmp_path / "none.toml"), "none.toml", "not found")
    bad = _write(tmp_path, "bad.toml", "[motor\nr_ohm = 1")
    _expect(lambda: load_bench(bad), "bad.toml", "not valid TOML")


def test_unknown_table_and_key(tmp_path):
    f = _bench_with(tmp_path, "[motr]\nr_ohm = 1.0\n")
    _expect(lambda: load_bench(f), "bench.toml", "[motr]", "unknown table")
    text = BENCH.read_text().replace("[motor]\n", "[motor]\nresistance = 1.0\n")
    f = _write(tmp_path, "bench2.toml", text)
    _expect(lambda: load_bench(f), "bench2.toml", "[motor]", "resistance = 1.0", "unknown key")


def test_wrong_type_is_a_config_error(tmp_path):
    text = BENCH.read_text().replace("r_ohm = 1.2", 'r_ohm = "1.2"')
    f = _write(tmp_path, "bench.toml", text)
    _expect(lambda: load_bench(f), "[motor]", "r_ohm", "'1.2'")


def test_firmware_table_error_and_cross_table_error(tmp_path):
    text = BENCH.read_text().replace("[servo]\n", "[servo]\narithmetic_mode = 1\n")
    f = _write(tmp_path, "a.toml", text)
    _expect(lambda: load_bench(f), "a.toml", "[servo]", "arithmetic_mode", "unknown key")
    text = re.sub(r"(?m)^current_limit_a = .*$", "current_limit_a = 9.0", BENCH.read_text())
    f = _write(tmp_path, "b.toml", text)
    _expect(lambda: load_bench(f), "b.toml", "[limits]", "current_limit_a = 9.0")


def test_firmware_and_plant_must_agree(tmp_path):
    f = _bench_with(tmp_path, "")
    text = f.read_text().replace("pwm_hz = 20e3", "pwm_hz = 10e3")
    f.write_text(text)
    _expect(lambda: load_bench(f), "[controller.current]", "pwm_arr", "7200")


def _exp(tmp_path: Path, head: str, commands: str = "") -> Path:
    return _write(tmp_path, "exp.toml", head + "\n" + commands)


GOOD_HEAD = f'bench = "{BENCH}"\nduration_s = 2.0\n'


def test_experiment_loads_commands_and_overrides(tmp_path):
    f = _exp(
        tmp_path,
        GOOD_HEAD + 'title = "t"\n[motor]\nr_ohm = 1.5\n',
        """
[[command]]
t_s = 0.5
type = "set_gains"
loop = "velocity"
kp = 0.01
ki = 0.1

[[command]]
t_s = 0.1
type = "move"
target_mdeg = 3e6
v_max_dps = 990.0
a_max_dps2 = 148.0
profile = "scurve"
j_max_dps3 = 1000
""",
    )
    exp = load_experiment(f)
    assert exp.bench.plant.motor.r_ohm == 1.5
    assert exp.bench.plant.motor.l_h == 0.6e-3  # the rest from the bench file
    assert [c.type for c in exp.commands] == ["move", "set_gains"]  # sorted by time
    move = exp.commands[0].message(7)
    assert move == Move(7, 3000.0, 990.0, 148.0, 1000.0, Profile.SCURVE)
    assert exp.commands[1].message(8) == SetGains(8, Loop.VELOCITY, 0.01, 0.1, 0.0)


def test_built_in_bench_by_name(tmp_path):
    exp = load_experiment(_exp(tmp_path, 'bench = "paper_bench.toml"\nduration_s = 1.0\n'))
    assert exp.bench.plant.gearbox.ratio == 80.0


@pytest.mark.parametrize(
    ("head", "parts"),
    [
        ("duration_s = 1.0\n", ["bench = None"]),
        ('bench = "nope.toml"\nduration_s = 1.0\n', ["nope.toml", "no such file"]),
        (f'bench = "{BENCH}"\n', ["duration_s = None"]),
        (f'bench = "{BENCH}"\nduration_s = -1.0\n', ["duration_s = -1.0"]),
        (f'bench = "{BENCH}"\nduration_s = true\n', ["duration_s = True"]),
        (f'bench = "{BENCH}"\nduration_s = 1.0\ntitle = 3\n', ["title = 3"]),
        (f'bench = "{BENCH}"\nduration_s = 1.0\nspeed = 3\n', ["speed = 3", "unknown key"]),
        (f'bench = "{BENCH}"\nduration_s = 1.0\ncommand = 3\n', ["command = 3"]),
        (
            f'bench = "{BENCH}"\nduration_s = 1.0\n[motor]\nr_ohm = -2.0\n',
            ["exp.toml", "[motor]", "r_ohm = -2.0"],
        ),
    ],
)
def test_experiment_top_level_errors(tmp_path, head, parts):
    f = _exp(tmp_path, head)
    _expect(lambda: load_experiment(f), str(f.name), *parts)


MOVE_OK = 'type = "move"\ntarget_deg = 10.0\nv_max_dps = 100.0\na_max_dps2 = 100.0\n'


@pytest.mark.parametrize(
    ("body", "parts"),
    [
        ('t_s = 0.1\ntype = "jump"\n', ["command #1", "type = 'jump'"]),
        ("t_s = 0.1\n", ["command #1", "type = None"]),
        ('t_s = "soon"\n' + MOVE_OK, ["t_s = 'soon'"]),
        ("t_s = -0.1\n" + MOVE_OK, ["t_s = -0.1"]),
        ("t_s = 2.0\n" + MOVE_OK, ["t_s = 2.0", "duration_s"]),
        ("t_s = 0.1\n" + MOVE_OK + "speed = 3\n", ["speed = 3", "not a field"]),
        (
            "t_s = 0.1\n" + MOVE_OK.replace("100.0\n", '"fast"\n', 1),
            ["v_max_dps = 'fast'", "number"],
        ),
        (
            "t_s = 0.1\n" + MOVE_OK.replace("a_max_dps2 = 100.0", "a_max_dps2 = nan"),
            ["a_max_dps2 = nan", "finite"],
        ),
        ("t_s = 0.1\n" + MOVE_OK + 'profile = "cubic"\n', ["profile = 'cubic'"]),
        ("t_s = 0.1\n" + MOVE_OK.replace("target_deg = 10.0\n", ""), ["give exactly one"]),
        ("t_s = 0.1\n" + MOVE_OK + "target_mdeg = 1.0\n", ["give exactly one"]),
        (
            't_s = 0.1\ntype = "move"\ntarget_deg = 1.0\na_max_dps2 = 1.0\n',
            ["v_max_dps = <missing>"],
        ),
        (
            't_s = 0.1\ntype = "set_gains"\nloop = "torque"\nkp = 1.0\nki = 1.0\n',
            ["loop = 'torque'"],
        ),
        ('t_s = 0.1\ntype = "set_enable"\nenable = 1\n', ["enable = 1", "true or false"]),
        ('t_s = 0.1\ntype = "set_telemetry"\ndecimation = 1.5\n', ["decimation = 1.5", "integer"]),
        ('t_s = 0.1\ntype = "raw"\nhex = "zz"\n', ["hex = 'zz'"]),
        ('t_s = 0.1\ntype = "raw"\nhex = 5\n', ["hex = 5"]),
    ],
)
def test_command_errors(tmp_path, body, parts):
    f = _exp(tmp_path, GOOD_HEAD, "[[command]]\n" + body)
    _expect(lambda: load_experiment(f), "exp.toml", *parts)


def test_every_command_type_builds_its_message(tmp_path):
    from sim.config import COMMAND_FIELDS

    samples = {
        "float": "1.0",
        "int": "2",
        "bool": "true",
        "profile": '"trapezoid"',
        "loop": '"position"',
        "hex": '"a55a"',
        "queue_action": '"hold"',
        "stream_action": '"status"',
        "interp": '"cubic"',
    }
    body = ""
    # program and stream entries read files and expand into many commands
    # (tests/sim/test_motionfile.py)
    single = {c: s for c, s in COMMAND_FIELDS.items() if "path" not in {k for _, k in s.values()}}
    for ctype, spec in single.items():
        body += f'[[command]]\nt_s = 0.5\ntype = "{ctype}"\n'
        for key, (_required, kind) in spec.items():
            if key == "target_mdeg":
                continue
            body += f"{key} = {samples[kind]}\n"
    exp = load_experiment(_exp(tmp_path, GOOD_HEAD, body))
    built = [c.message(k + 1) for k, c in enumerate(exp.commands)]
    assert len(built) == len(single)
    assert built[-1] == bytes.fromhex("a55a")
    assert {type(m).__name__ for m in built[:-1]} >= {"Hello", "Move", "Stop", "SetEnable"}


# ---------------------------------------- issue #11 §5: each case a one-line ConfigError


def _one_line(call, *parts: str) -> str:
    text = _expect(call, *parts)
    assert "\n" not in text
    return text


def test_a_list_in_a_gain_or_plant_field_is_refused(tmp_path):
    text = BENCH.read_text()
    f = _write(
        tmp_path, "g.toml", re.sub(r"(?m)^kp_a_per_dps = .*$", "kp_a_per_dps = [0.01]", text)
    )
    _one_line(lambda: load_bench(f), "[controller.velocity]", "kp_a_per_dps = [0.01]", "not a list")
    f = _write(tmp_path, "g2.toml", re.sub(r"(?m)^kp_per_s = .*$", "kp_per_s = [1.0, 2.0]", text))
    _one_line(lambda: load_bench(f), "[controller.position]", "kp_per_s = [1.0, 2.0]")
    f = _bench_with(tmp_path, "")
    f.write_text(f.read_text().replace("r_ohm = 1.2", "r_ohm = [[1.2]]"))
    _one_line(lambda: load_bench(f), "[motor]", "r_ohm = [[1.2]]", "not a list")


def test_unreadable_files_are_config_errors(tmp_path):
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes(b'title = "b\xe9nch"\n')
    _one_line(lambda: load_bench(latin1), "latin1.toml", "not UTF-8", "0xe9", "offset 10")
    _one_line(lambda: load_experiment(latin1), "latin1.toml", "not UTF-8")
    _one_line(lambda: load_bench(tmp_path), str(tmp_path), "is a folder")
    exp = _exp(tmp_path, f'bench = "{tmp_path}"\nduration_s = 1.0\n')
    _one_line(lambda: load_experiment(exp), "bench =", "no such file")


@pytest.mark.parametrize(
    ("table", "key", "value", "reason"),
    [
        ("encoder", "bits", "12", "written for the AS5048's 14 bits"),
        ("encoder", "bits", "16", "(bits = 14; firmware_model/units.py)"),
        ("gearbox", "ratio", "100.0", "written for the 80:1 gearmotor"),
        ("gearbox", "ratio", "79.9", "no other value is accepted"),
    ],
)
def test_values_the_firmware_hard_codes_are_refused(tmp_path, table, key, value, reason):
    f = _bench_with(tmp_path, "")
    pattern = re.compile(rf"(^\[{table}\]\n(?:(?!^\[).*\n)*?){key} = [^\n]*\n", re.M)
    f.write_text(pattern.sub(rf"\g<1>{key} = {value}\n", f.read_text(), count=1))
    _one_line(lambda: load_bench(f), f"[{table}] {key} = {value}", reason)


def test_hard_coded_values_are_refused_as_simulation_overrides_too():
    from sim.loop import Simulation

    bench = load_bench(BENCH)
    with pytest.raises(ConfigError, match=r"\[gearbox\] ratio = \[80.0, 70.0\]"):
        Simulation(bench, batch=2, overrides={"gearbox.ratio": [80.0, 70.0]})
    with pytest.raises(ConfigError, match=r"overrides: \[encoder\] bits = 10"):
        Simulation(bench, overrides={"encoder.bits": 10})
    # a plant spread around the firmware's nominal values stays possible (robustness)
    Simulation(bench, batch=2, overrides={"supply.voltage_v": [20.0, 26.0]})


@pytest.mark.parametrize(
    ("extra", "parts"),
    [
        ("[safety]\nwatchdog_s = 0.001\n", ["[safety] watchdog_s = 0.001", "one servo tick"]),
        ("[safety]\nwatchdog_s = 0.002\n", ["watchdog_s = 0.002", "(0.002 s at servo.tick_hz"]),
        (
            "[safety]\nwatchdog_s = 0.004\n[servo]\ntick_hz = 200.0\n",
            ["[safety] watchdog_s = 0.004", "0.005 s at servo.tick_hz = 200"],
        ),
        (
            f"[uart]\nfifo_bytes = {LARGEST_FRAME - 1}\n",
            [f"fifo_bytes = {LARGEST_FRAME - 1}", f"({LARGEST_FRAME} bytes, {LARGEST_NAME})"],
        ),
        ("[uart]\nfifo_bytes = 16\n", ["[uart] fifo_bytes = 16", "largest frame"]),
        (
            "[telemetry]\nheartbeat_s = 0.0005\n",
            ["[telemetry] heartbeat_s = 0.0005", "at least one servo tick (0.002 s"],
        ),
        ("[motor]\nr_ohm = 1e400\n", ["[motor] r_ohm = inf", "finite"]),
        (
            "[belt]\nsmall_teeth = 100000000000000000000\n",
            ["[belt] small_teeth", "must be in [8, 1000] (a timing pulley)"],
        ),
    ],
)
def test_sizes_that_cannot_work_are_refused(tmp_path, extra, parts):
    f = _exp(tmp_path, GOOD_HEAD + extra)
    assert "exp.toml" in _one_line(lambda: load_experiment(f), *parts)


def test_heartbeat_none_or_at_least_a_tick_is_accepted(tmp_path):
    for value in ("0.0", "0.002", "0.25"):
        f = _exp(tmp_path, GOOD_HEAD + f"[telemetry]\nheartbeat_s = {value}\n")
        assert load_experiment(f).bench.firmware.telemetry.heartbeat_s == float(value)


def test_watchdog_off_or_longer_than_a_tick_is_accepted(tmp_path):
    for value in ("0.0", "0.0021", "0.5"):
        f = _exp(tmp_path, GOOD_HEAD + f"[safety]\nwatchdog_s = {value}\n")
        assert load_experiment(f).bench.firmware.safety.watchdog_s == float(value)


@pytest.mark.parametrize(
    ("body", "parts"),
    [
        (
            'type = "move"\ntarget_mdeg = 3e9\nv_max_dps = 990.0\na_max_dps2 = 148.0',
            ["command #1", "target_mdeg = 3000000000.0", "Move.target_deg holds -214748.3649"],
        ),
        (
            'type = "move"\ntarget_deg = 1.0\nv_max_dps = 1e39\na_max_dps2 = 148.0',
            ["v_max_dps = 1e+39", "does not fit the wire"],
        ),
        (
            'type = "set_gains"\nloop = "velocity"\nkp = 1e40\nki = 0.0',
            ["kp = 1e+40", "SetGains.kp holds"],
        ),
        ('type = "set_telemetry"\ndecimation = 70000', ["decimation = 70000", "0 .. 65535"]),
        ('type = "set_telemetry"\ndecimation = -1', ["decimation = -1", "0 .. 65535"]),
        ('type = "stop"\na_max_dps2 = -1e39', ["a_max_dps2 = -1e+39", "Stop.a_max_dps2"]),
    ],
)
def test_command_values_that_do_not_fit_the_wire(tmp_path, body, parts):
    f = _exp(tmp_path, GOOD_HEAD, f"[[command]]\nt_s = 0.0\n{body}\n")
    _one_line(lambda: load_experiment(f), "exp.toml", *parts)


def test_cross_field_errors_name_the_wrong_key(tmp_path):
    f = _exp(tmp_path, GOOD_HEAD + "[limits]\nv_max_dps = 2000.0\n")
    _one_line(lambda: load_experiment(f), "[limits] v_max_dps = 2000.0", "safety.over_speed_dps")
    f = _bench_with(tmp_path, "")
    f.write_text(f.read_text().replace("voltage_v = 24.0", "voltage_v = 20.0"))
    _one_line(lambda: load_bench(f), "[controller.current] supply_v = 24.0", "[supply] gives 20.0")


def test_members_of_a_valid_batch_are_its_arrays_picked_as_floats():
    # PlantParams.member(k) copies without checking again (each check holds element by
    # element); what it gives is what dataclasses.replace with the checks would give.
    import dataclasses

    base = sim_params.PlantParams()
    motor = dataclasses.replace(base.motor, r_ohm=np.array([1.0, 1.3, 1.6]), l_h=0.7e-3)
    belt = dataclasses.replace(base.belt, damping_nm_s_rad=np.array([0.01, 0.02, 0.03]))
    params = dataclasses.replace(base, motor=motor, belt=belt)
    for k in range(3):
        m = params.member(k)
        want = dataclasses.replace(
            base,
            motor=dataclasses.replace(base.motor, r_ohm=float(motor.r_ohm[k]), l_h=0.7e-3),
            belt=dataclasses.replace(base.belt, damping_nm_s_rad=float(belt.damping_nm_s_rad[k])),
        )
        assert m == want
        assert type(m.motor.r_ohm) is float and m.batch_size() is None
        assert m.gearbox is params.gearbox  # a table without arrays is shared, not copied
    assert base.member(0) == base  # no arrays: the parameters themselves
