"""The navigation CSV (imulink.io.nav_input): a simulated drive written and read back, and
every kind of bad input refused in one line naming the line."""
from __future__ import annotations

import numpy as np
import pytest

from imulink.io import nav_input
from imulink.io.sensor_input import InputError
from imulink.sim import navigation as nv
from imulink.sim import simulate


@pytest.fixture(scope="module")
def drive():
    traj = nv.car_drive(60.0, 100.0, seed=1)
    return traj, simulate(traj, seed=1), nv.gnss_fixes(traj, nv.GnssModel(rate_hz=5.0), seed=1), nv.baro_samples(
        traj, seed=1)


def test_a_simulated_drive_reads_back_as_written(tmp_path, drive):
    traj, imu, fixes, baro = drive
    path = tmp_path / "drive.csv"
    nav_input.write_nav_csv(path, imu, fixes, baro, truth=traj)
    got = nav_input.read_nav_csv(path)
    assert len(got) == len(traj)
    np.testing.assert_array_equal(got.timestamp_us, np.arange(len(traj)) * 10_000)
    np.testing.assert_allclose(got.gyr, imu.gyr, rtol=1e-8)
    np.testing.assert_allclose(got.acc, imu.acc, rtol=1e-8)
    np.testing.assert_allclose(got.mag, imu.mag, rtol=1e-8)
    np.testing.assert_array_equal(got.baro_index, baro.index)
    np.testing.assert_allclose(got.baro_pa, baro.pressure_pa, atol=5e-4)
    np.testing.assert_array_equal(got.fix_index, fixes.index)
    np.testing.assert_allclose(got.fix_lat_deg, fixes.lat_deg, atol=1e-9)
    np.testing.assert_allclose(got.fix_height_m, fixes.height_m, atol=1e-4)
    np.testing.assert_allclose(got.fix_vel_enu, fixes.vel_enu, atol=1e-5)
    np.testing.assert_allclose(got.fix_h_acc_m, 2.5)


def test_markers_are_fixes_without_velocity(tmp_path, drive):
    traj, imu, _, _ = drive
    markers = nv.marker_fixes(traj, every_s=20.0, accuracy_m=0.1, seed=3)
    path = tmp_path / "walk.csv"
    nav_input.write_nav_csv(path, imu, markers)
    got = nav_input.read_nav_csv(path)
    np.testing.assert_array_equal(got.fix_index, [2000, 4000])
    np.testing.assert_allclose(got.fix_v_acc_m, 0.1)
    assert np.all(np.isnan(got.fix_vel_enu)) and got.mag is not None and len(got.baro_index) == 0


HEADER = ("timestamp_us,gyr_x_rad_s,gyr_y_rad_s,gyr_z_rad_s,acc_x_m_s2,acc_y_m_s2,acc_z_m_s2,"
          "gnss_lat_deg,gnss_lon_deg,gnss_height_m,gnss_h_acc_m,gnss_v_acc_m,"
          "gnss_vel_e_m_s,gnss_vel_n_m_s,gnss_vel_u_m_s,gnss_s_acc_m_s,baro_pa,baro_temp_c,truth_x")
GOOD = ["0,0,0,0,0,0,9.8,47.1,8.5,400,2.5,5,0,0,0,0.1,96000,25,1",
        "10000,0,0,0,0,0,9.8,,,,,,,,,,,,2"]


@pytest.mark.parametrize("rows, message", [
    (["20000,0,0,0,0,0,9.8,,,,,,,,,,,,3", "10000,0,0,0,0,0,9.8,,,,,,,,,,,,4"],
     "line 5: timestamp_us 10000 does not follow 20000"),
    (["20000,0,nan,0,0,0,9.8,,,,,,,,,,,,3"], "line 4: gyr_y_rad_s is 'nan'"),
    (["20000,0,0,0,0,0,x9.8,,,,,,,,,,,,3"], "line 4: acc_z_m_s2 is not a number ('x9.8')"),
    (["20000,0,0,0,0,0,9.8,95,8.5,400,2.5,5,,,,,,,3"], "line 4: gnss_lat_deg 95 is not a latitude"),
    (["20000,0,0,0,0,0,9.8,47,181,400,2.5,5,,,,,,,3"], "line 4: gnss_lon_deg 181 is not a longitude"),
    (["20000,0,0,0,0,0,9.8,47,8,,2.5,5,,,,,,,3"], "line 4: gnss_height_m empty beside gnss_lat_deg"),
    (["20000,0,0,0,0,0,9.8,47,8,400,0,5,,,,,,,3"], "line 4: a fix's accuracies must be positive"),
    (["20000,0,0,0,0,0,9.8,,,,,,1,2,3,0.1,,,3"], "line 4: a GNSS velocity without a position"),
    (["20000,0,0,0,0,0,9.8,,,,,,,,,,96000,,3"], "line 4: baro_temp_c empty beside baro_pa"),
    (["20000,0,0,0,0,0,9.8"], "line 4: 7 cells, the header has 19"),
])
def test_bad_rows_are_refused_naming_the_line(tmp_path, rows, message):
    path = tmp_path / "bad.csv"
    path.write_text("\n".join([HEADER, *GOOD, *rows]) + "\n")
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        nav_input.read_nav_csv(path)


def test_a_good_csv_with_every_kind_of_row_reads(tmp_path):
    path = tmp_path / "good.csv"
    path.write_text("\n".join([HEADER, *GOOD, "20000,0,0,0,0,0,9.8,47.2,8.6,401,3,6,,,,,,,3"]) + "\n")
    got = nav_input.read_nav_csv(path)
    np.testing.assert_array_equal(got.fix_index, [0, 2])
    assert np.isnan(got.fix_vel_enu[1]).all() and got.fix_vel_enu[0].tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_array_equal(got.baro_index, [0])
    assert got.mag is None


@pytest.mark.parametrize("header, message", [
    ("timestamp_us,gyr_x_rad_s,gyr_y_rad_s,acc_x_m_s2,acc_y_m_s2,acc_z_m_s2", "gyr_z_rad_s are missing"),
    (HEADER.replace(",baro_temp_c", ""), "baro_temp_c missing beside baro_pa"),
    (HEADER.replace("gnss_lat_deg,", ""), "gnss_lat_deg missing beside"),
])
def test_missing_columns_are_named(tmp_path, header, message):
    path = tmp_path / "cols.csv"
    path.write_text(header + "\n")
    with pytest.raises(InputError, match=message):
        nav_input.read_nav_csv(path)


def test_a_missing_file_and_a_directory_are_refused(tmp_path):
    with pytest.raises(InputError, match="nothing.csv"):
        nav_input.read_nav_csv(tmp_path / "nothing.csv")
    with pytest.raises(InputError):
        nav_input.read_nav_csv(tmp_path)
