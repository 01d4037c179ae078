#!/usr/bin/env python3
"""ladar-odometer and KISS-ICP side by side on one recording, both scored against its truth.

Replays RECORDING through `ladar-odometer replay --out DIR` (timed), reads back from DIR the
scans it decoded (estimate.mcap: foxglove.LaserScan per scanner, foxglove.FrameTransform for
the mounts), merges the two scanners' scans of each pair into one frame of points in the body
frame, runs KISS-ICP on those frames (no IMU; timed per frame), and prints for both: velocity
error std N, E, D (m/s), attitude error std roll, pitch, yaw (mrad), horizontal error at the
end (m), and time per frame. The recording must carry /truth (any `simulate` output does).
Our velocity and attitude are what the autopilot is told (every ODOMETRY message of
mavlink.tlog, usable or not); KISS-ICP's velocity is its poses differenced between frames.

    pip install kiss-icp mcap pymavlink
    cargo build --release
    target/release/ladar-odometer simulate --scenario open-room --out /tmp/open-room.mcap
    python3 tools/kiss_icp_compare.py /tmp/open-room.mcap [--method map]

KISS-ICP is run with its defaults but for what a 30 m indoor 2D scanner pair needs: a 30 m
range, no deskew (the scans are short and the fusion's deskew is not KISS-ICP's to use), and a
0.1 m voxel (its default comes from the range and would merge a room's walls into few voxels).
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.kiss_icp import KissICP
from mcap.reader import make_reader
from pymavlink import mavutil

#: Two scans make one frame if their first readings are at most this far apart, s.
MAX_PAIR_SKEW_S = 0.15


def quaternion_matrix(w, x, y, z):
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def stamp(message):
    return message["timestamp"]["sec"] + 1e-9 * message["timestamp"]["nsec"]


def read_scans(estimate_mcap):
    """Each scanner's scans as (time, points in its own frame), and each mount (R, t) in body."""
    scans, mounts = {}, {}
    with open(estimate_mcap, "rb") as file:
        for _, channel, raw in make_reader(file).iter_messages():
            if channel.topic == "/tf":
                message = json.loads(raw.data)
                if message["parent_frame_id"] == "body":
                    r, t = message["rotation"], message["translation"]
                    mounts[message["child_frame_id"]] = (
                        quaternion_matrix(r["w"], r["x"], r["y"], r["z"]),
                        np.array([t["x"], t["y"], t["z"]]),
                    )
            elif channel.topic.startswith("/scan/"):
                message = json.loads(raw.data)
                ranges = np.array(
                    [np.nan if r is None else r for r in message["ranges"]], dtype=float
                )
                angles = np.linspace(
                    message["start_angle"], message["end_angle"], len(ranges)
                )
                valid = np.isfinite(ranges) & (ranges > 0.05)
                points = np.stack(
                    [
                        ranges[valid] * np.cos(angles[valid]),
                        ranges[valid] * np.sin(angles[valid]),
                        np.zeros(valid.sum()),
                    ],
                    axis=1,
                )
                scans.setdefault(message["frame_id"], []).append((stamp(message), points))
    return scans, mounts


def frames(scans, mounts):
    """Pairs each scan of the first scanner with the nearest of the second: (time, body points)."""
    names = sorted(scans)
    if len(names) != 2 or any(name not in mounts for name in names):
        sys.exit(f"need two scanners with mounts in estimate.mcap, found {names}")
    first, second = (scans[name] for name in names)
    second_times = np.array([t for t, _ in second])
    out = []
    for t, points in first:
        k = int(np.argmin(np.abs(second_times - t)))
        if abs(second_times[k] - t) > MAX_PAIR_SKEW_S:
            continue
        body = []
        for name, (_, scan_points) in zip(names, [(t, points), second[k]]):
            rotation, translation = mounts[name]
            body.append(scan_points @ rotation.T + translation)
        out.append((0.5 * (t + second_times[k]), np.vstack(body)))
    return out


def read_tum(path):
    data = np.loadtxt(path)
    return data[:, 0], data[:, 1:4], data[:, 4:8]  # qx qy qz qw


def interpolate(times, values, at):
    return np.stack([np.interp(at, times, values[:, k]) for k in range(values.shape[1])], axis=1)


def rotations(quaternions_xyzw):
    return [quaternion_matrix(q[3], q[0], q[1], q[2]) for q in quaternions_xyzw]


def nearest_rotations(times, quaternions, at):
    index = np.clip(np.searchsorted(times, at), 0, len(times) - 1)
    return rotations(quaternions[index])


def rotation_log(matrix):
    angle = np.arccos(np.clip((np.trace(matrix) - 1) / 2, -1.0, 1.0))
    if angle < 1e-12:
        return np.zeros(3)
    axis = np.array(
        [
            matrix[2, 1] - matrix[1, 2],
            matrix[0, 2] - matrix[2, 0],
            matrix[1, 0] - matrix[0, 1],
        ]
    ) / (2 * np.sin(angle))
    return axis * angle


def truth_velocity(truth, at):
    """Truth velocity at `at`: its 50 Hz positions differenced, interpolated."""
    truth_t, truth_p, _ = truth
    middle = 0.5 * (truth_t[1:] + truth_t[:-1])
    velocity = np.diff(truth_p, axis=0) / np.diff(truth_t)[:, None]
    return interpolate(middle, velocity, at)


def score(times, velocities, attitudes, end_position, truth, from_s):
    """Velocity and attitude error std over `times` from `from_s`, and the end error."""
    truth_t, truth_p, truth_q = truth
    keep = times >= from_s
    times, velocities = times[keep], velocities[keep]
    attitudes = [a for a, k in zip(attitudes, keep) if k]
    velocity_error = velocities - truth_velocity(truth, times)
    true_attitudes = nearest_rotations(truth_t, truth_q, times)
    attitude_error = np.array(
        [rotation_log(a @ b.T) for a, b in zip(attitudes, true_attitudes)]
    )
    end_error = end_position[1] - interpolate(truth_t, truth_p, np.array([end_position[0]]))[0]
    return {
        "velocity_error_std_ned": velocity_error.std(axis=0),
        "attitude_error_std_mrad": 1000 * attitude_error.std(axis=0),
        "horizontal_error_end_m": float(np.hypot(end_error[0], end_error[1])),
    }


def read_odometry(tlog):
    """ODOMETRY messages: times, NED velocities and attitudes as the autopilot reads them."""
    link = mavutil.mavlink_connection(str(tlog), dialect="common")
    times, velocities, attitudes = [], [], []
    while (message := link.recv_match(type="ODOMETRY")) is not None:
        attitude = quaternion_matrix(*message.q)
        times.append(message.time_usec * 1e-6)
        velocities.append(attitude @ np.array([message.vx, message.vy, message.vz]))
        attitudes.append(attitude)
    return np.array(times), np.array(velocities), attitudes


def run_kiss_icp(frame_list, truth, from_s):
    config = KISSConfig()
    config.data.max_range = 30.0
    config.data.min_range = 0.1
    config.data.deskew = False
    config.mapping.voxel_size = 0.1
    odometry = KissICP(config)
    times, poses, seconds = [], [], []
    for t, points in frame_list:
        started = time.perf_counter()
        odometry.register_frame(points, np.zeros(len(points)))
        seconds.append(time.perf_counter() - started)
        times.append(t)
        poses.append(odometry.last_pose.copy())
    # KISS-ICP starts at the first frame's body pose: put that pose where the truth has it.
    truth_t, truth_p, truth_q = truth
    start = np.eye(4)
    start[:3, :3] = nearest_rotations(truth_t, truth_q, np.array([times[0]]))[0]
    start[:3, 3] = interpolate(truth_t, truth_p, np.array([times[0]]))[0]
    world = [start @ pose for pose in poses]
    times = np.array(times)
    positions = np.array([pose[:3, 3] for pose in world])
    middle = 0.5 * (times[1:] + times[:-1])
    velocities = np.diff(positions, axis=0) / np.diff(times)[:, None]
    attitudes = [pose[:3, :3] for pose in world]
    figures = score(
        middle, velocities, attitudes[1:], (times[-1], positions[-1]), truth, from_s
    )
    return figures, float(np.median(seconds))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path, help="a recording with /truth (simulate's)")
    parser.add_argument(
        "--binary",
        type=Path,
        default=Path("target/release/ladar-odometer"),
        help="the ladar-odometer to replay with (default: target/release/ladar-odometer)",
    )
    parser.add_argument(
        "--from-s",
        type=float,
        default=10.0,
        help="score from this time on, s (default 10: the built-in scenes' still start)",
    )
    parser.add_argument(
        "--method",
        choices=["pairs", "map"],
        help="replay with this odometer (replay --method) instead of the recorded one",
    )
    arguments = parser.parse_args()
    if not arguments.binary.exists():
        sys.exit(f"{arguments.binary} not found: run `cargo build --release` or pass --binary")
    with tempfile.TemporaryDirectory() as out:
        started = time.perf_counter()
        method = ["--method", arguments.method] if arguments.method else []
        subprocess.run(
            [arguments.binary, "replay", arguments.recording, "--out", out, *method],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        replay_s = time.perf_counter() - started
        truth = read_tum(Path(out) / "truth.tum")
        ours_t, ours_p, _ = read_tum(Path(out) / "trajectory.tum")
        odometry = read_odometry(Path(out) / "mavlink.tlog")
        frame_list = frames(*read_scans(Path(out) / "estimate.mcap"))
    if not frame_list:
        sys.exit("no scan pairs in the replay's estimate.mcap")
    ours = score(*odometry, (ours_t[-1], ours_p[-1]), truth, arguments.from_s)
    kiss, kiss_s = run_kiss_icp(frame_list, truth, arguments.from_s)
    # The whole replay (decoding, 400 Hz IMU, every epoch) over the frames it had.
    ours_s = replay_s / len(frame_list)
    print(f"{arguments.recording.name}: {len(frame_list)} frames, scored from {arguments.from_s} s")
    print("| method | velocity error std N, E, D (m/s) | attitude error std r, p, y (mrad) | horizontal error at the end (m) | time per frame |")
    print("|---|---|---|---|---|")
    for name, figures, seconds in [
        (f"ladar-odometer{', ' + arguments.method if arguments.method else ''} (whole replay)", ours, ours_s),
        ("KISS-ICP (registration only)", kiss, kiss_s),
    ]:
        velocity = ", ".join(f"{v:.3f}" for v in figures["velocity_error_std_ned"])
        attitude = ", ".join(f"{a:.1f}" for a in figures["attitude_error_std_mrad"])
        print(
            f"| {name} | {velocity} | {attitude} | {figures['horizontal_error_end_m']:.2f} | {1000 * seconds:.2f} ms |"
        )


if __name__ == "__main__":
    main()
