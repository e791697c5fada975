"""The CSV log format (models.logs): one test per kind of malformed log, units, derived speeds."""

import math

import numpy as np
import pytest

from models.errors import ConfigError, DataError
from models.logs import Log, read_csv


def write(tmp_path, text, name="log.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


GOOD = "t [s],omega1 [rad/s],n1 [N]\n0,1,20\n0.01,1.1,20\n0.02,1.2,20\n0.03,1.3,20\n"


def test_good_log_reads(tmp_path):
    log = read_csv(write(tmp_path, GOOD), required=("omega1", "n1"))
    np.testing.assert_allclose(log.t, [0, 0.01, 0.02, 0.03])
    np.testing.assert_allclose(log["omega1"], [1, 1.1, 1.2, 1.3])
    assert log.dt == pytest.approx(0.01)


def test_missing_required_channel(tmp_path):
    with pytest.raises(DataError, match=r"missing required column 'n2'"):
        read_csv(write(tmp_path, GOOD), required=("n2",))


def test_missing_time_column(tmp_path):
    with pytest.raises(DataError, match=r"missing required column 't \[s\]'"):
        read_csv(write(tmp_path, "omega1 [rad/s]\n1\n2\n"))


@pytest.mark.parametrize("value, what", [("nan", "nan"), ("inf", "inf"), ("-inf", "-inf")])
def test_non_finite(tmp_path, value, what):
    text = GOOD.replace("0.02,1.2,20", f"0.02,{value},20")
    with pytest.raises(DataError, match=rf"column 'omega1' row 3 \(line 4\): expected a finite number, got {what}"):
        read_csv(write(tmp_path, text))


def test_non_numeric(tmp_path):
    text = GOOD.replace("0.01,1.1,20", "0.01,1.1,abc")
    with pytest.raises(DataError, match=r"column 'n1' row 2 \(line 3\): expected a number, got 'abc'"):
        read_csv(write(tmp_path, text))


@pytest.mark.parametrize("t2", ["0.01", "0.005"])
def test_non_increasing_time(tmp_path, t2):
    text = GOOD.replace("0.02,1.2,20", f"{t2},1.2,20")
    with pytest.raises(DataError, match=r"column 't' row 3 \(line 4\): time must be strictly increasing"):
        read_csv(write(tmp_path, text))


def test_gap(tmp_path):
    text = GOOD + "0.04,1.4,20\n0.09,1.5,20\n0.10,1.6,20\n"
    with pytest.raises(DataError, match=r"column 't' row 6 \(line 7\): gap of 0.05 s"):
        read_csv(write(tmp_path, text))


@pytest.mark.parametrize("column, header, match", [
    pytest.param("omega1 [rad/s]", "omega1 [furlong]",
                 r"unit \[furlong\] cannot be converted to \[rad/s\] for column 'omega1'", id="unknown_unit"),
    pytest.param("omega1 [rad/s]", "omega1 [N]", r"unit \[N\] cannot be converted to \[rad/s\]",
                 id="wrong_dimension_unit"),
    pytest.param("omega1 [rad/s]", "omega1", r"header column 2 must look like 'name \[unit\]'",
                 id="header_without_unit"),
    pytest.param("n1 [N]", "omega1 [rpm]", r"channel 'omega1' appears twice", id="duplicate_column"),
])
def test_bad_header(tmp_path, column, header, match):
    with pytest.raises(DataError, match=match):
        read_csv(write(tmp_path, GOOD.replace(column, header)))


def test_units_are_case_sensitive(tmp_path):
    """mN is milli-, MN mega-newton; a lower-case 'mn' is no unit at all."""
    text = "t [s],motor_torque [%s]\n0,1\n0.01,2\n"
    with pytest.raises(DataError, match=r"unit \[mn m\] cannot be converted"):
        read_csv(write(tmp_path, text % "mn m"))
    log = read_csv(write(tmp_path, text % "MN m", "b.csv"))
    np.testing.assert_allclose(log["motor_torque"], [1e6, 2e6])


def test_free_channel_names_take_the_quantity_of_their_unit(tmp_path):
    log = read_csv(write(tmp_path, "t [s],omega9 [rad/s],wob [kN],bit_temp [s]\n0,1,2,3\n0.01,1,2,3\n"))
    assert log.units == {"omega9": "rad/s", "wob": "N", "bit_temp": "s"}
    np.testing.assert_allclose(log["wob"], [2000, 2000])
    with pytest.raises(DataError, match=r"unit \[furlong\] cannot be converted for column 'speed'"):
        read_csv(write(tmp_path, "t [s],speed [furlong]\n0,1\n0.01,1\n", "b.csv"))


def test_excel_byte_order_mark_is_accepted(tmp_path):
    p = tmp_path / "excel.csv"
    p.write_bytes(b"\xef\xbb\xbf" + GOOD.encode())
    log = read_csv(p, required=("omega1",))
    np.testing.assert_allclose(log["omega1"], [1, 1.1, 1.2, 1.3])


@pytest.mark.parametrize("row, n", [("0.02,1.2", 2), ("0.02,1.2,20,4", 4)])
def test_wrong_row_length(tmp_path, row, n):
    text = GOOD.replace("0.02,1.2,20", row)
    with pytest.raises(DataError, match=rf"row 3 \(line 4\): expected 3 values, got {n}"):
        read_csv(write(tmp_path, text))


def test_empty_and_missing_file(tmp_path):
    with pytest.raises(DataError, match="empty file"):
        read_csv(write(tmp_path, "\n"))
    with pytest.raises(DataError, match="not found"):
        read_csv(tmp_path / "nope.csv")


def test_excel_csv_with_byte_order_mark(tmp_path):
    """Excel's "CSV UTF-8" export starts with a byte-order mark and ends lines with CRLF."""
    p = tmp_path / "excel.csv"
    p.write_bytes(b"\xef\xbb\xbf" + GOOD.replace("\n", "\r\n").encode("utf-8"))
    log = read_csv(p, required=("omega1", "n1"))
    np.testing.assert_allclose(log.t, [0, 0.01, 0.02, 0.03])
    np.testing.assert_allclose(log["n1"], [20, 20, 20, 20])
    assert "t" not in log.channels and not any("\ufeff" in c for c in log.channels)


def test_too_short(tmp_path):
    with pytest.raises(DataError, match="at least 2 samples"):
        read_csv(write(tmp_path, "t [s],omega1 [rad/s]\n0,1\n"))


def test_unit_conversions(tmp_path):
    text = ("t [ms],omega1 [rpm],theta2 [deg],n1 [kN],motor_torque [N mm],omega3 [deg/s],theta1 [rev]\n"
            "0,60,90,0.02,500,180,1\n10,30,180,0.01,250,360,2\n20,0,270,0,0,0,3\n")
    log = read_csv(write(tmp_path, text))
    np.testing.assert_allclose(log.t, [0, 0.01, 0.02])
    np.testing.assert_allclose(log["omega1"], [2 * math.pi, math.pi, 0])
    np.testing.assert_allclose(log["theta2"], [math.pi / 2, math.pi, 1.5 * math.pi])
    np.testing.assert_allclose(log["n1"], [20, 10, 0])
    np.testing.assert_allclose(log["motor_torque"], [0.5, 0.25, 0])
    np.testing.assert_allclose(log["omega3"], [math.pi, 2 * math.pi, 0])
    np.testing.assert_allclose(log["theta1"], [2 * math.pi, 4 * math.pi, 6 * math.pi])
    # theta2 has no speed column: omega2 is derived (pi/2 rad per 10 ms)
    np.testing.assert_allclose(log["omega2"], [50 * math.pi] * 3)
    assert "omega2" in log.derived and "omega1" not in log.derived


def test_exact_case_milli_newton(tmp_path):
    log = read_csv(write(tmp_path, "t [s],motor_torque [mN m],n1 [mN]\n0,1000,500\n0.01,2000,500\n"))
    np.testing.assert_allclose(log["motor_torque"], [1, 2])
    np.testing.assert_allclose(log["n1"], [0.5, 0.5])


def test_angles_only_give_derived_speeds(tmp_path):
    t = np.arange(0, 1, 0.01)
    th = 0.5 * t ** 2 + 2 * t  # speed 2 + t
    rows = "\n".join(f"{a:.6f},{b:.12f}" for a, b in zip(t, th))
    log = read_csv(write(tmp_path, "t [s],theta_drive [rad]\n" + rows + "\n"))
    assert "omega_drive" in log.derived
    np.testing.assert_allclose(log["omega_drive"][1:-1], 2 + t[1:-1], atol=1e-6)


def test_roundtrip_and_no_overwrite(tmp_path):
    log = read_csv(write(tmp_path, GOOD))
    out = tmp_path / "out.csv"
    log.write_csv(out)
    back = read_csv(out)
    np.testing.assert_allclose(back["omega1"], log["omega1"])
    with pytest.raises(ConfigError, match="refusing to overwrite"):
        log.write_csv(out)


def test_log_object_validates():
    with pytest.raises(DataError, match="unknown channel 'speed': give its unit"):
        Log(np.arange(3.0), {"speed": np.zeros(3)})
    with pytest.raises(DataError, match=r"column 'omega1' has shape \(2,\), expected \(3,\)"):
        Log(np.arange(3.0), {"omega1": np.zeros(2)})
