"""trajectory.csv and pose_corrections.csv: what is written reads back, and bad tables give one-line errors."""

import numpy as np
import pytest

from featmap.errors import InputFileError
from featmap.io.pose_csv import corrections_csv_text, read_corrections_csv, read_trajectory_xy, trajectory_csv_text
from featmap.refinement.base import apply_corrections


def test_pose_corrections_round_trip_to_the_poses_a_run_fused_with(tmp_path):
    rng = np.random.default_rng(3)
    frames = [0, 2, 5, 9]
    corrections = np.column_stack([rng.normal(0, 0.3, (4, 2)), rng.normal(0, 0.02, 4)])
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, :2, 3] = rng.uniform(-500, 500, (4, 2))
    path = tmp_path / "pose_corrections.csv"
    path.write_text(corrections_csv_text(frames, corrections))
    read_frames, read = read_corrections_csv(path)
    assert read_frames.tolist() == frames
    # 0.1 mm and 1e-5 deg in the file: a point 100 m from the sensor lands within 0.2 mm of where it was.
    point = np.array([100.0, 0.0, 0.0, 1.0])
    exact = apply_corrections(poses, corrections) @ point
    again = apply_corrections(poses, read) @ point
    assert np.abs(exact - again).max() < 2e-4


def test_trajectory_round_trip(tmp_path):
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, 3] = [[1.23456, -2.0, 0.5], [3.0, 4.0, 0.5], [5.5, 6.5, 0.6]]
    path = tmp_path / "trajectory.csv"
    path.write_text(trajectory_csv_text([0, 1, 2], poses))
    assert np.allclose(read_trajectory_xy(path), poses[:, :2, 3], atol=1e-4)


@pytest.mark.parametrize("text, says", [
    ("frame,x,y\n0,1,2\n", "not a pose-corrections table frame,dx_m,dy_m,dyaw_deg (its header is 'frame,x,y')"),
    ("frame,dx_m,dy_m,dyaw_deg\n0,0.1,0.2\n", "not a pose-corrections table frame,dx_m,dy_m,dyaw_deg"),
    ("frame,dx_m,dy_m,dyaw_deg\n0,0.1,nan,0\n", "pose_corrections.csv:2: not a pose-corrections table frame,dx_m,dy_m,dyaw_deg (a value that is not a finite number)"),
    ("frame,dx_m,dy_m,dyaw_deg\n0,0,0,0\n\n1,0.1,0.2\n", "pose_corrections.csv:4: not a pose-corrections table frame,dx_m,dy_m,dyaw_deg (expected 4 values, found 3)"),
    ("frame,dx_m,dy_m,dyaw_deg\n0;0.1,0.2,0.3,0\n", "pose_corrections.csv:2: not a pose-corrections table frame,dx_m,dy_m,dyaw_deg (not a number: '0;0.1')"),
    ("frame,dx_m,dy_m,dyaw_deg\n0.5,0.1,0.2,0\n", "frame numbers that are not whole numbers"),
    ("frame,dx_m,dy_m,dyaw_deg\n1e30,0.1,0.2,0\n", "frame numbers that are not whole numbers of a sensible size"),
    ("", "not a pose-corrections table frame,dx_m,dy_m,dyaw_deg"),
])
def test_bad_pose_corrections_name_the_file(tmp_path, text, says):
    path = tmp_path / "pose_corrections.csv"
    path.write_text(text)
    with pytest.raises(InputFileError) as err:
        read_corrections_csv(path)
    assert str(path) in str(err.value) and says in str(err.value) and "\n" not in str(err.value)


def test_a_missing_trajectory_names_the_file(tmp_path):
    with pytest.raises(InputFileError, match="trajectory.csv: not a trajectory table frame,x,y,z,yaw"):
        read_trajectory_xy(tmp_path / "trajectory.csv")


def test_a_table_with_only_its_header_is_empty_and_quiet(tmp_path, recwarn):
    path = tmp_path / "trajectory.csv"
    path.write_text("frame,x,y,z,yaw\n")
    assert read_trajectory_xy(path).shape == (0, 2)
    assert not recwarn.list
