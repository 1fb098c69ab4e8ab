"""BENCHMARKS.md from a run's saved results (``bench.report``): every section in order, the targets' verdicts, a
benchmark that could not complete reported as such. No benchmark runs here; the results are written out."""

from __future__ import annotations

import pytest

from bench.report import report

MACHINE = {"cpu": "test CPU", "cores": 2, "kernel": "6.1", "python": "3.11", "packages": {"numpy": "2"},
           "rmw": "rmw_fastrtps_cpp (default)", "executor": "EventsExecutor", "domain_id": 70,
           "load_average_at_start": (0.2, 0.1, 0.1), "load_average_at_end": (0.5, 0.2, 0.1)}
HEADINGS = ["## 1. Closed-loop latency", "### 1b. The controller's share", "## 2. Lockstep throughput",
            "## 3. Region-of-attraction sweep", "## 4. Network lockstep throughput", "## 5. Network realtime",
            "## 6. Memory per controller", "## 7. Authenticated battery commands"]


def latency_row(rate_hz: float, p50_ratio: float, misses: int = 0) -> dict:
    ms = {"p50": 0.5, "p99": 1.0, "max": 2.0}
    return {"rate_hz": rate_hz, "duration_s": 30.0, "rounds": 3, "pingpong_ms": ms, "loop_ms": ms,
            "p50_ratio": p50_ratio, "round_ratios": [p50_ratio] * 3, "loop_deadline_misses": misses,
            "pingpong_deadline_misses": 0, "loop_measurements": 3000, "loop_jitter_p99_ms": 0.1}


def lockstep_row(throughput: float, floor_ratio: float, **extra) -> dict:
    ms = {"p50": 0.2, "p99": 0.4}
    return {"rate_hz": 100.0, "rounds": 3, "sim_duration_s": 60.0, "run_wall_s": 60.0 / throughput,
            "throughput": throughput, "floor_throughput": throughput * floor_ratio, "floor_ratio": floor_ratio,
            "round_ratios": [floor_ratio] * 3, "round_trip_mean_ms": 0.3, "cycle_ms": 10.0 / throughput,
            "latency_ms": ms, "turnaround_ms": ms, "deadline_misses": 0, **extra}


def network_row(case: str, generators: int, deployment: str, floor_ratio: float) -> dict:
    return lockstep_row(20.0, floor_ratio, case=case, generators=generators, deployment=deployment, partial=None)


def realtime_result() -> dict:
    loop = {"p50": 0.6, "p99": 1.2, "deadline_misses": 0, "measurements": 1500}
    floor = {"p50": 0.4, "p99": 0.8, "max": 1.0, "mean": 0.45, "deadline_misses": 0}
    kinds = ("separate", "composed")
    gens = [{"namespace": f"gen{i}", "machine": f"bus{i}", **{kind: loop for kind in kinds},
             **{f"{kind}_floor": floor for kind in kinds}} for i in (1, 2)]
    memory = {"separate_kib": [60000, 61000], "composed_kib": [80000], "separate_cpu": [0.05, 0.06],
              "composed_cpu": [0.08], "separate_echo_kib": [40000, 41000], "composed_echo_kib": [45000]}
    return {"case": "kundur_two_area", "generators": gens, "size": 2, "rate_hz": 50.0, "duration_s": 30.0,
            "rounds": 3, "kinds": kinds, "memory": memory}


def results(latency_ratio: float = 1.2, network_ratio: float = 1.8) -> dict:
    share_ms = {"p50": 0.4, "p99": 0.9, "max": 1.0, "mean": 0.45}
    return {
        "latency": [latency_row(50.0, 1.1), latency_row(100.0, latency_ratio)],
        "controller-share": [{"round": 1, "echo": share_ms, "controller": share_ms}],
        "lockstep": [lockstep_row(30.0, 1.2)],
        "roa": {"grid": "200 x 200 x 4", "vectorised_s": 2.0, "loop_runs": 800, "loop_s": 30.0,
                "per_trajectory_ms": 37.0, "loop_extrapolated_s": 6000.0, "speedup": 3000.0,
                "disagreement_fraction": 0.001, "step_s": 0.01,
                "per_b": [{"b": 0.3, "vectorised_s": 0.5, "cells": 40000,
                           "boundary": {"cells": 800, "checked": 100, "disagree": 1},
                           "interior": {"cells": 39200, "checked": 100, "disagree": 0}}]},
        "network-lockstep": [network_row("smib", 1, "separate", 1.2),
                             network_row("kundur_two_area", 4, "separate", 1.5),
                             network_row("ieee39", 10, "separate", network_ratio)],
        "network-realtime": realtime_result(),
        "command-auth": COMMAND_AUTH,
    }


COMMAND_AUTH = {"bare_publish_us": 12.5, "sign_us": 3.25, "sealed_publish_us": 16.0, "verify_us": 4.5,
                "batch": 2000, "batches": 15}


def page(results: dict, machine: dict = MACHINE, quick: bool = False) -> str:
    return report("bench/run_all", machine, quick, results, "2026-01-01 00:00 UTC", 100.0)


def test_every_section_in_order_and_each_left_out_when_its_benchmark_did_not_run():
    text = page(results())
    places = [text.index(heading) for heading in HEADINGS]
    assert places == sorted(places)
    assert text.index("## Machine") < places[0]
    only_roa = page({"roa": results()["roa"]})
    assert [heading for heading in HEADINGS if heading in only_roa] == ["## 3. Region-of-attraction sweep"]


@pytest.mark.parametrize(("ratio", "verdict"), [(1.2, "met;"), (1.4, "**not met**;")])
def test_the_latency_target_at_100_per_s_is_judged_on_its_p50_ratio(ratio, verdict):
    assert f"Targets at 100/s: p50 ratio {ratio:.2f} <= 1.3: {verdict}" in page(results(latency_ratio=ratio))


@pytest.mark.parametrize(("ratio", "verdict"), [(1.8, "met."), (2.5, "**not met**.")])
def test_the_network_target_is_judged_at_ten_generators(ratio, verdict):
    text = page(results(network_ratio=ratio))
    assert f"Target at N = 10 (separate): within 2x of the floor ({ratio:.2f}): {verdict}" in text
    assert "Cost per added generator, separate (least-squares slope over N = 4, 10)" in text


def test_a_benchmark_that_could_not_complete_is_reported_with_its_error_beside_the_rows_that_did():
    run = results()
    run["network-lockstep"].append({"case": "kundur_ring_52", "deployment": "composed", "error": "plant exited"})
    run["network-realtime"] = {"error": "no summary"}
    text = page(run)
    assert "| - | kundur_ring_52: **not completed**: plant exited | composed |" in text
    assert "| 10 | ieee39 | separate |" in text
    assert "## 5. Network realtime (issue 14)\n\n**Not completed**: no summary" in text
    assert "## 6. Memory" not in text


def test_a_loaded_machine_and_a_quick_run_are_flagged():
    assert "Measured on a loaded machine" not in page(results())
    assert "--quick` run" not in page(results())
    loaded = {**MACHINE, "load_average_at_start": (1.5, 1.0, 1.0)}
    assert "Measured on a loaded machine" in page(results(), loaded)
    assert "> **`--quick` run**" in page(results(), quick=True)


def test_the_command_authentication_row_sets_sign_and_verify_beside_the_bare_publish():
    text = page({"command-auth": COMMAND_AUTH})
    assert "median of 15 batches of 2000 commands" in text
    assert ("| bare publish (µs) | sign (µs) | sealed publish (µs) | added by the seal (µs) | verify (µs) |"
            in text)
    assert "| 12.50 | 3.25 | 16.00 | +3.50 | 4.50 |" in text
