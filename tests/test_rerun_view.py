"""Round-trip tests of the Rerun views: write .rrd files, verify them, read them back.

rerun-sdk 0.41 no longer has ``rr.dataframe.load_recording``/``load_archive``;
files are read back chunk by chunk with :class:`rerun.chunk.RrdReader`, whose
chunks convert to pyarrow record batches (one column per timeline and component).
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from nni_msgs_adapter.viewing.palette import colour_hex, colour_rgb
from nni_msgs_adapter.viewing.rerun_layout import PHASE_PATH, blueprint, run_paths
from nni_msgs_adapter.viewing.rerun_live import LiveLogger
from nni_msgs_adapter.viewing.rerun_stream import open_recording
from nni_msgs_adapter.viewing.rerun_trajectory import log_trajectory

RERUN_CLI = Path(sys.executable).parent / "rerun"
TIMELINE = "sim_time"
N_SAMPLES = 5000
RUNS = {"b=0.3": 0.3, "b=inf": math.inf}


def damped_run(b: float, n: int = N_SAMPLES) -> dict[str, np.ndarray]:
    """Synthetic damped swing: time (s), d (rad), d' (rad/s), P_ST (pu), flags, W_hat."""
    t = np.linspace(0.0, 5.0, n)
    omega_n, zeta = 2.0 * math.pi * 1.2, 0.15
    envelope = 0.2 * np.exp(-zeta * omega_n * t)
    d = envelope * np.cos(omega_n * t)
    d_dot = np.gradient(d, t)
    w = -1.1 * d - 0.4 * d_dot / omega_n
    return {
        "t_s": t,
        "angle_dev_rad": d,
        "speed_dev_rad_s": d_dot,
        "battery_power_pu": np.clip(w, -b, b),
        "saturated": np.abs(w) >= b,
        "w_hat": 0.5 * d_dot**2 / omega_n**2 + 0.5 * d**2,
    }


def omega_ellipse(m: int = 200) -> np.ndarray:
    """An open (m, 2) stand-in for the boundary of Omega (rad, rad/s)."""
    phi = np.linspace(0.0, 2.0 * math.pi, m, endpoint=False)
    return np.column_stack([1.2 * np.cos(phi), 3.5 * np.sin(phi)])


def write_batch(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """Log every run of ``RUNS`` with ``log_trajectory`` to ``path``; return the inputs."""
    recording, url = open_recording("nni_test_batch", ("save", path))
    assert url is None
    runs = {label: damped_run(b) for label, b in RUNS.items()}
    for label, b in RUNS.items():
        log_trajectory(recording, label, **runs[label], b=b, f0_hz=50.0, omega_boundary=omega_ellipse())
    recording.flush()
    recording.disconnect()
    return runs


def write_live(path: Path, segment_samples: int = 40, n: int = N_SAMPLES) -> dict[str, dict[str, np.ndarray]]:
    """Log every run of ``RUNS`` sample by sample with ``LiveLogger`` to ``path``; return the inputs."""
    recording, _ = open_recording("nni_test_live", ("save", path))
    runs = {label: damped_run(b, n) for label, b in RUNS.items()}
    for label, b in RUNS.items():
        logger = LiveLogger(recording, label, b, 50.0, omega_ellipse(), segment_samples=segment_samples)
        run = runs[label]
        for k in range(run["t_s"].size):
            logger.log(**{key: values[k] for key, values in run.items()})
        logger.flush()
    recording.flush()
    recording.disconnect()
    return runs


def read_entities(path: Path) -> dict[str, list[pa.RecordBatch]]:
    """Group the record batches of the first recording in ``path`` by entity path."""
    batches: dict[str, list[pa.RecordBatch]] = {}
    for chunk in RrdReader(path).stream():
        batches.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return batches


def temporal_column(batches: list[pa.RecordBatch], column: str) -> tuple[np.ndarray, list]:
    """Concatenate a component column over the time-stamped batches, sorted by time (s)."""
    times, values = [], []
    for batch in batches:
        if TIMELINE in batch.schema.names:
            times.append(batch.column(TIMELINE).cast(pa.int64()).to_numpy() * 1e-9)
            values.extend(batch.column(column).to_pylist())
    t = np.concatenate(times)
    order = np.argsort(t, kind="stable")
    return t[order], [values[i] for i in order]


def scalars(batches: list[pa.RecordBatch]) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and values of a one-scalar-per-row ``Scalars`` entity."""
    t, values = temporal_column(batches, "Scalars:scalars")
    assert all(len(v) == 1 for v in values)
    return t, np.array([v[0] for v in values])


def static_value(batches: list[pa.RecordBatch], column: str) -> list:
    """The value of a static component column (a list: one entry per instance)."""
    static = [b for b in batches if TIMELINE not in b.schema.names and column in b.schema.names]
    assert len(static) == 1
    return static[0].column(column).to_pylist()[-1]


@pytest.fixture(scope="module")
def batch_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("rerun") / "batch.rrd"
    return path, write_batch(path)


@pytest.fixture(scope="module")
def live_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("rerun") / "live.rrd"
    return path, write_live(path)


@pytest.mark.parametrize("which", ["batch_file", "live_file"])
def test_rrd_verify(which: str, request: pytest.FixtureRequest) -> None:
    path, _ = request.getfixturevalue(which)
    result = subprocess.run([RERUN_CLI, "rrd", "verify", path], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("which", ["batch_file", "live_file"])
def test_scalars_round_trip(which: str, request: pytest.FixtureRequest) -> None:
    path, runs = request.getfixturevalue(which)
    entities = read_entities(path)
    for label, b in RUNS.items():
        run, paths = runs[label], run_paths(label)
        expected = {
            paths.angle: run["angle_dev_rad"],
            paths.frequency: run["speed_dev_rad_s"] / (2.0 * math.pi),
            paths.power: run["battery_power_pu"],
            paths.saturation: run["saturated"].astype(float),
            paths.w_hat: run["w_hat"],
        }
        for path_, values in expected.items():
            t, got = scalars(entities[path_])
            np.testing.assert_allclose(t, run["t_s"], rtol=0, atol=1e-9)
            np.testing.assert_array_equal(got, values)  # float64 scalars round-trip exactly
        assert static_value(entities[paths.parameters], "b") == [b]
        assert static_value(entities[paths.parameters], "f0_hz") == [50.0]
        if math.isfinite(b):
            for path_, limit in ((paths.limit_upper, b), (paths.limit_lower, -b)):
                t, got = scalars(entities[path_])
                assert t[0] == pytest.approx(run["t_s"][0]) and t[-1] == pytest.approx(run["t_s"][-1])
                np.testing.assert_array_equal(got, limit)
        else:
            assert paths.limit_upper not in entities and paths.limit_lower not in entities


@pytest.mark.parametrize("which", ["batch_file", "live_file"])
def test_phase_portrait_round_trip(which: str, request: pytest.FixtureRequest) -> None:
    path, runs = request.getfixturevalue(which)
    entities = read_entities(path)
    for label in RUNS:
        run, paths = runs[label], run_paths(label)
        t, strips = temporal_column(entities[paths.trajectory], "LineStrips2D:strips")
        assert t[-1] == pytest.approx(run["t_s"][-1])
        # Each row holds one segment; consecutive segments share their end point.
        segments = [np.array(row[0]) for row in strips]
        for previous, current in zip(segments, segments[1:]):
            np.testing.assert_array_equal(previous[-1], current[0])
        joined = np.vstack([segments[0]] + [s[1:] for s in segments[1:]])
        expected = np.column_stack([run["angle_dev_rad"], run["speed_dev_rad_s"]])
        np.testing.assert_allclose(joined, expected, rtol=1e-6, atol=1e-6)  # float32 points

        boundary = np.array(static_value(entities[paths.omega_boundary], "LineStrips2D:strips")[0])
        np.testing.assert_allclose(boundary[:-1], omega_ellipse(), rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(boundary[0], boundary[-1])


def test_batch_and_live_write_same_entities(batch_file: tuple, live_file: tuple) -> None:
    batch, live = set(read_entities(batch_file[0])), set(read_entities(live_file[0]))
    assert batch == live
    expected = {p for label in RUNS for p in run_paths(label)}
    expected -= {run_paths("b=inf").limit_upper, run_paths("b=inf").limit_lower}
    expected -= {run_paths(label).charge for label in RUNS}  # only a battery of finite energy has one
    assert expected <= batch and not {run_paths(label).charge for label in RUNS} & batch


def test_blueprint_is_stored(batch_file: tuple) -> None:
    assert len(RrdReader(batch_file[0]).blueprints()) == 1


def test_live_segments_are_bounded(tmp_path: Path) -> None:
    runs = write_live(tmp_path / "live.rrd", segment_samples=10, n=1001)
    strips = read_entities(tmp_path / "live.rrd")[run_paths("b=0.3").trajectory]
    _, rows = temporal_column(strips, "LineStrips2D:strips")
    assert max(len(row[0]) for row in rows) == 11
    assert len(rows) == math.ceil((runs["b=0.3"]["t_s"].size - 1) / 10)


def test_phase_axes_and_colours(batch_file: tuple) -> None:
    entities = read_entities(batch_file[0])
    scale = static_value(entities[PHASE_PATH], "Transform3D:scale")
    assert scale == [[1.0, -1.0, 1.0]]  # y-flip: d' points up
    axes = np.array(static_value(entities[PHASE_PATH], "LineStrips2D:strips"))
    assert axes.shape == (2, 2, 2) and np.all(axes[0, :, 1] == 0) and np.all(axes[1, :, 0] == 0)
    labels = static_value(entities[PHASE_PATH], "Points2D:labels")
    assert {"d (rad)", "d' (rad/s)", "1", "-3", "3"} <= set(labels)
    colors = [static_value(entities[run_paths(label).angle], "SeriesLines:colors") for label in RUNS]
    # Rerun packs a colour as 0xRRGGBBAA: each run has its b's colour, the figures' own (palette).
    assert [c[0] >> 8 for c in colors] == [int(colour_hex(b)[1:], 16) for b in RUNS.values()]


def test_no_battery_draws_zero_limits(tmp_path: Path) -> None:
    recording, _ = open_recording("nni_test_b0", ("save", tmp_path / "b0.rrd"))
    run = damped_run(0.0, n=100)
    paths = log_trajectory(recording, "b=0", **run, b=0.0, f0_hz=50.0, color=colour_rgb(math.inf))
    recording.disconnect()
    entities = read_entities(tmp_path / "b0.rrd")
    for path in (paths.limit_upper, paths.limit_lower):
        np.testing.assert_array_equal(scalars(entities[path])[1], 0.0)
    np.testing.assert_array_equal(scalars(entities[paths.saturation])[1], 1.0)
    assert paths.omega_boundary not in entities


def test_invalid_inputs() -> None:
    recording, _ = open_recording("nni_test_invalid", ("save", "/dev/null"))
    run = damped_run(0.3, n=10)
    with pytest.raises(ValueError, match=">= 0"):
        log_trajectory(recording, "bad", **run, b=-0.1, f0_hz=50.0)
    with pytest.raises(ValueError, match="shape"):
        LiveLogger(recording, "bad", 0.3, 50.0, omega_boundary=np.zeros(6))
    with pytest.raises(ValueError, match="segment_samples"):
        log_trajectory(recording, "bad", **run, b=0.3, f0_hz=50.0, segment_samples=0)
    run["w_hat"] = run["w_hat"][:-1]
    with pytest.raises(ValueError, match="common"):
        log_trajectory(recording, "bad", **run, b=0.3, f0_hz=50.0)
    with pytest.raises(ValueError, match="sink"):
        open_recording("nni_test_invalid", ("print", None))
    recording.disconnect()


def test_blueprint_file(tmp_path: Path) -> None:
    path = tmp_path / "layout.rbl"
    blueprint(timeline="pmu_time", phase_bounds=((-1.0, 1.6), (-2.0, 4.5))).save("nni_test", path)
    result = subprocess.run([RERUN_CLI, "rrd", "verify", path], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    reader = RrdReader(path)
    stored = {}
    for chunk in reader.stream(store=reader.blueprints()[0]):
        batch = chunk.to_record_batch()
        for name in ("VisualBounds2D:range", "VisibleTimeRanges:ranges"):
            if name in batch.schema.names:
                stored[name] = batch.column(name).to_pylist()[-1][0]
    # Bounds are given with d' up and stored for the y-down 2D space.
    assert stored["VisualBounds2D:range"] == {"x_range": [-1.0, 1.6], "y_range": [-4.5, 2.0]}
    assert stored["VisibleTimeRanges:ranges"]["timeline"] == "pmu_time"


def test_step_signals_are_never_averaged_and_every_series_says_its_unit(batch_file: tuple) -> None:
    """A 0/1 flag drawn at default zoom must not show 0.5, nor a held battery power a mean of two values."""
    entities = read_entities(batch_file[0])
    paths = run_paths("b=0.3")
    for path in (paths.saturation, paths.power, paths.limit_upper, paths.limit_lower):
        assert static_value(entities[path], "SeriesLines:aggregation_policy") == [1], path  # Off
        assert static_value(entities[path], "SeriesLines:interpolation_mode") == [2], path  # StepAfter
    names = {path: static_value(entities[path], "SeriesLines:names")[0]
             for path in (paths.angle, paths.frequency, paths.power, paths.saturation, paths.w_hat)}
    assert names == {paths.angle: "d (rad) b=0.3", paths.frequency: "Δf (Hz) b=0.3",
                     paths.power: "P_ST (pu) b=0.3", paths.saturation: "saturated (0/1) b=0.3",
                     paths.w_hat: "W_hat (pu rad) b=0.3"}
    assert static_value(entities[paths.omega_boundary], "LineStrips2D:labels") == ["Omega b=0.3"]


def test_runs_in_separate_files_overlay_when_merged(tmp_path: Path) -> None:
    """Two processes' files (as two replays or two live runs write them) merge into one recording with both runs."""
    for label, b in RUNS.items():
        recording, _ = open_recording("nni_battery_control", ("save", tmp_path / f"{label}.rrd"))
        log_trajectory(recording, label, **damped_run(b, n=100), b=b, f0_hz=50.0)
        recording.disconnect()
    merged = tmp_path / "merged.rrd"
    result = subprocess.run([RERUN_CLI, "rrd", "merge", *[tmp_path / f"{label}.rrd" for label in RUNS], "-o", merged],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    reader = RrdReader(merged)
    assert len(reader.recordings()) == 1  # one recording: the viewer shows both runs in the same views
    entities = read_entities(merged)
    for label in RUNS:
        t, _ = scalars(entities[run_paths(label).angle])
        assert t.size == 100


def test_time_series_views_show_simulated_seconds_from_zero(tmp_path: Path) -> None:
    """Every time-series view: x axis from t = 0 s on, linked across views, all of each run visible."""
    path = tmp_path / "layout.rbl"
    blueprint().save("nni_test", path)
    reader = RrdReader(path)
    axes, ranges = [], []
    for chunk in reader.stream(store=reader.blueprints()[0]):
        batch = chunk.to_record_batch()
        if "TimeAxis:view_range" in batch.schema.names:
            axes.append((batch.column("TimeAxis:view_range").to_pylist()[-1][0],
                         batch.column("TimeAxis:link").to_pylist()[-1][0]))
        if "VisibleTimeRanges:ranges" in batch.schema.names:
            ranges.append(batch.column("VisibleTimeRanges:ranges").to_pylist()[-1][0])
    assert axes == [({"start": 0, "end": None}, 2)] * 5  # five time-series views, linked to the global axis
    assert ranges.count({"timeline": TIMELINE, "range": {"start": None, "end": None}}) == 5
