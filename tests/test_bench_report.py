"""BENCHMARKS.md from a run's saved results (``bench.report``): every section in order, the targets' verdicts, a
benchmark that could not complete reported as such. No benchmark runs here; the results are written out."""

from __future__ import annotations

import pytest

from bench.report import report, splice

MACHINE = {"cpu": "test CPU", "cores": 2, "kernel": "6.1", "python": "3.11", "packages": {"numpy": "2"},
           "rmw": "rmw_fastrtps_cpp (default)", "executor": "EventsExecutor", "domain_id": 70,
           "load_average_at_start": (0.2, 0.1, 0.1), "load_average_at_end": (0.5, 0.2, 0.1)}
HEADINGS = ["## 1. Closed-loop latency", "### 1b. The controller's share", "## 2. Lockstep throughput",
            "## 3. Region-of-attraction sweep", "## 4. Network lockstep throughput", "## 5. Network realtime",
            "## 6. Memory per controller", "## 8. Latency the C37.118 path adds to the loop",
            "## 9. Authenticated commands and measurements",
            "## 10. C37.118 PMU server: frames per second and reporting latency",
            "## 11. Contingency screen: serial beside a 2-worker LocalCluster",
            "## 12. The Foxglove bridge and a client that never reads",
            "## 13. Law comparison beside a per-trajectory scipy loop",
            "## 14. Every bus fault of IEEE 118 and 300"]


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
    return {"case": "kundur_two_area", "generators": gens, "size": 2, "rate_hz": 50.0, "round_s": 30.0,
            "rounds": 3, "kinds": kinds, "memory": memory}


def c37118_loop_result(added_ms: float) -> dict:
    ros = {"p50": 0.3, "p99": 0.8, "max": 1.5, "deadline_misses": 0, "measurements": 1500}
    return {"rate_hz": 50.0, "duration_s": 30.0, "rounds": 3, "ros": ros,
            "c37118": {**ros, "p50": 0.3 + added_ms, "deadline_misses": 1}, "added_p50_ms": added_ms,
            "round_added_ms": [added_ms] * 3}


def c37118_server_result(p99_ms: float) -> dict:
    rows = [{"stations": n, "bytes": 16 + 40 * n, "encode_us": 5.0, "offer_us": 6.0, "server_fps": 100000.0,
             "floor_fps": 40000.0, "floor_ratio": 0.4} for n in (1, 10, 52)]
    latency = {"stations": 10, "rate_hz": 50, "duration_s": 30.0, "frames": 1500, "received": 1500, "p50": 0.7,
               "p99": p99_ms, "max": 6.0, "mean": 0.8, "offer_late_ms": {"p50": 0.2, "p99": 1.5, "max": 3.0,
                                                                        "mean": 0.3}, "frames_dropped": 0}
    return {"frames": 20000, "rows": rows, "latency": latency}


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
        "c37118-loop": c37118_loop_result(0.6),
        "command-auth": COMMAND_AUTH,
        "c37118-server": c37118_server_result(3.0),
        "screening": screening_result(40.0, 0.5),
        "foxglove": foxglove_result(),
        "law-comparison": law_comparison_result(26.0),
        "screening-large": large_screens_result(),
    }


def large_screens_result() -> dict:
    engine = {"engine": "LocalCluster", "workers": 2, "wall_s": 600.0, "compute_s": 1188.0}
    return {"quick": False, "limits": ("0", "0.3"), "screens": [
        {"case": "ieee118", "engine": engine, "command_s": 603.0, "contingencies": 118, "skipped": 0, "rows": 236,
         "weakest": {"0": [("bus:59", 0.425, False, "G25@59")], "0.3": [("bus:1", 1.0, True, "G54@116")]}}]}


def test_the_large_screens_report_their_time_and_their_weakest_contingencies_the_search_limit_marked():
    text = page({"screening-large": large_screens_result()})
    assert "| ieee118 | 118 | 0 | 236 | 600 | 603 | 0.197 | 1.0 % |" in text
    assert "| ieee118 | 0 | bus:59 0.425 (G25@59) |" in text
    assert "| ieee118 | 0.3 | bus:1 >= 1.000 (G54@116) |" in text


def foxglove_result(stalled: float = 0.9, reading: float = 1.5, spread: float = 1.2) -> dict:
    """Section 12's result: rounds' throughputs chosen so that the ratios are ``reading`` and ``stalled``."""
    return {"rounds": 1, "sim_s": 30.0, "rate_hz": 100.0, "ratios": {"reading": [reading], "stalled": [stalled]},
            "ratio": {"reading": reading, "stalled": stalled}, "spread": spread,
            "throughput": {"alone": 24.0, "reading": 24.0 / reading, "stalled": 24.0 / reading / stalled},
            "latency_p50_ms": {"alone": 0.25, "reading": 0.36, "stalled": 0.32}, "misses": 0}


def screen_run(engine: str, workers: int, wall_s: float, compute_s: float, contingencies: int = 39) -> dict:
    return {"engine": {"engine": engine, "workers": workers, "tasks": contingencies, "compute_s": compute_s,
                       "wall_s": wall_s}, "command_s": wall_s + 3.0, "contingencies": contingencies, "skipped": 0}


def screening_result(cluster_wall_s: float, idle_s: float, andes=None) -> dict:
    """Serial 76 s; the cluster's two workers computing 76 s over ``cluster_wall_s`` less ``idle_s`` each."""
    return {"quick": False, "limits": ("0", "0.1", "0.3", "inf"), "same_rows": True,
            "serial": screen_run("serial", 0, 76.0, 76.0),
            "cluster": screen_run("LocalCluster", 2, cluster_wall_s, 2 * (cluster_wall_s - idle_s)),
            "rates": [{"case": "ieee118", **screen_run("LocalCluster", 2, 80.0, 150.0, 8)}],
            "n1": screen_run("LocalCluster", 2, 116.0, 220.0, 109),
            "andes_fault": {"bus": 16, "fault_x": 1e-4, "duration_s": 5.0, "cct_max_s": 0.6, "ours_s": 0.5,
                            "ours_cct_s": 0.153, "andes": andes}}


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


@pytest.mark.parametrize(("ratio", "worst", "verdict"), [(1.4, 1.9, "met."), (1.6, 1.6, "**not met**."),
                                                       (1.4, 2.1, "**not met**.")])
def test_the_network_targets_judge_the_median_round_and_the_worst(ratio, worst, verdict):
    run = results(network_ratio=ratio)
    run["network-lockstep"][-1]["round_ratios"] = [ratio, ratio, worst]
    text = page(run)
    assert (f"- N = 10 (separate): floor / throughput {ratio:.2f} (median) <= 1.5, its worst round {worst:.2f} "
            f"<= 2: {verdict}") in text
    assert "- N = 4 (separate): floor / throughput 1.50 (median) <= 1.5, its worst round 1.50 <= 2: met." in text
    assert "- N = 4 (composed): not measured in this run." in text
    assert "Cost per added generator, separate (least-squares slope over N = 4, 10)" in text


@pytest.mark.parametrize(("throughput", "turnaround", "verdict"), [(3.2, 0.4, "met."), (2.9, 0.6, "**not met**.")])
def test_the_ring_and_the_turnaround_targets(throughput, turnaround, verdict):
    run = results()
    ring = network_row("kundur_ring_52", 52, "composed", 1.4)
    ring["throughput"] = throughput
    run["network-lockstep"].append(ring)
    run["network-lockstep"][2]["turnaround_ms"] = {"p50": turnaround, "p99": 1.0}
    text = page(run)
    assert f"- N = 52 (composed): {throughput:.1f}x real time >= 3: {verdict}" in text
    assert f"- N = 10 (separate): the plant's turnaround p50 {turnaround:.3f} ms <= 0.5 ms: {verdict}" in text


def test_a_separate_row_says_the_plants_turnaround_on_a_core_of_its_own_beside_the_shared_one():
    run = results()
    run["network-lockstep"][2]["pinned"] = {"turnaround_ms": 0.42, "cycle_ms": 2.5, "plant_cpu": 0}
    text = page(run)
    assert ("- N = 10 (separate): turnaround p50 0.420 ms (shared: 0.200 ms), cycle 2.500 ms "
            "(shared: 0.500 ms).") in text
    assert "with the plant's threads on CPU 0 and the controllers' on the others" in text
    assert "The plant on a core of its own" not in page(results())


@pytest.mark.parametrize(("composed", "separate", "floor", "verdicts"),
                         [(0, 3, 3, ("met.", "met.")), (1, 4, 3, ("**not met**.", "**not met**."))])
def test_the_realtime_targets_count_misses_against_zero_and_the_floor(composed, separate, floor, verdicts):
    run = results()
    gens = run["network-realtime"]["generators"]
    gens[0]["composed"] = {**gens[0]["composed"], "deadline_misses": composed}
    gens[0]["separate"] = {**gens[0]["separate"], "deadline_misses": separate}
    gens[0]["separate_floor"] = {**gens[0]["separate_floor"], "deadline_misses": floor}
    text = page(run)
    assert f"- composed: {composed} deadline misses = 0: {verdicts[0]}" in text
    assert f"- separate: {separate} deadline misses <= its fan-out floor's {floor}: {verdicts[1]}" in text


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


PLANT_STACKS = """\
<module> (nni_plant_sim/network_plant_node.py:86);run_node (nni_msgs_adapter/ros/node_main.py:164) 50
run_node (nni_msgs_adapter/ros/node_main.py:164);PlantNodeBase._on_command (nni_plant_sim/plant_node_base.py:209);\
NetworkPlantNode._integrate (nni_plant_sim/network_plant_node.py:70);rk4_network (nni_plant_sim/network_rk4.py:116) 7
run_node (nni_msgs_adapter/ros/node_main.py:164);PlantNodeBase._publish (nni_plant_sim/plant_node_base.py:{pmu});\
StampedPublisher.publish (nni_msgs_adapter/ros/loop_node.py:27);Publisher.publish (rclpy/publisher.py:72) 30
run_node (nni_msgs_adapter/ros/node_main.py:164);PlantNodeBase._publish (nni_plant_sim/plant_node_base.py:{clock});\
StampedPublisher.publish (nni_msgs_adapter/ros/loop_node.py:27) 3
 400
Node.destroy_node (rclpy/node.py:1965) 2
"""


def _line_of(path: str, text: str) -> int:
    from pathlib import Path

    import nni_plant_sim
    lines = (Path(nni_plant_sim.__file__).parent / path).read_text().splitlines()
    return next(number for number, line in enumerate(lines, 1) if text in line)


def test_the_profile_sorts_each_sample_into_its_part_by_its_frames_and_the_source_line_they_run():
    from bench.network_profile import EXECUTOR, PLANT_PARTS, classify

    stacks = PLANT_STACKS.format(pmu=_line_of("plant_node_base.py", "pub.publish(sample.stamp_ns"),
                                 clock=_line_of("plant_node_base.py", "self._clock_pub.publish("))
    counts = classify(stacks, PLANT_PARTS)
    assert counts == {EXECUTOR: 50, "RK4 over the machines and the network solve": 7, "publish: N measurements": 30,
                      "publish: /clock": 3, "other": 2}  # the thread with no Python frame is left out


def test_the_profile_section_gives_each_part_its_share_and_its_time_per_loop_sample():
    from bench.network_profile import SAMPLING_HZ

    parts = [("publish: N measurements", 600), ("executor (waiting, or its C++ dispatch)", 400)]
    profile = {"case": "ieee39", "deployment": "composed", "sim_s": 2.0, "rate_hz": 50.0, "loop_samples": 100,
               "wall_s": 1.0, "size": 10, "turnaround_ms": 0.4,
               "processes": [{"process": "plant", "cpu_s": 0.5, "samples_seen": 1000, "parts": parts}]}
    text = page({"network-profile": profile})
    assert "## 7. Where a network lockstep sample's time goes (issue 23)" in text
    assert "**plant** (sampled 1.00 s of its executor thread): 0.50 s of CPU in all threads, 5000 us per loop" in text
    assert f"| publish: N measurements | 60.0 % | {600 / SAMPLING_HZ * 1e6 / 100:.1f} |" in text
    assert f"The plant's measurement publishes: {600 / SAMPLING_HZ * 1e6 / 100 / 10:.1f} us per message" in text
    assert "## 7. Where a network lockstep sample's time goes (issue 23)\n\n**Not completed**: py-spy failed" in page(
        {"network-profile": {"error": "py-spy failed"}})


def test_the_profile_section_sets_each_process_beside_its_transport_alone():
    transport = {"plant_us": 1500.0, "ping_us": 900.0, "controllers_us": 1200.0, "echoes_us": 1000.0,
                 "cycle_ms": 1.3, "round_trip_ms": 1.0}
    profile = {"case": "ieee39", "deployment": "composed", "sim_s": 2.0, "rate_hz": 50.0, "loop_samples": 100,
               "wall_s": 1.0, "size": 10, "turnaround_ms": 0.4, "transport": transport,
               "processes": [{"process": "plant", "cpu_s": 0.5, "samples_seen": 10, "parts": [("other", 10)]}]}
    text = page({"network-profile": profile})
    assert "| plant | 1500 | ping | 900 | 600 | 60.0 |" in text
    assert "| controllers (composed) | 1200 | echoes | 1000 | 200 | 20.0 |" in text
    assert "(cycle 1.300 ms) and of a chained fan-out to 10 echoes deployed alike" in text
    assert "(a publish at one end, a take and its callback at the other): 95.0 us of CPU, 2N messages" in text


def test_a_controllers_clock_reads_are_its_readers_not_its_publishes():
    from bench.network_profile import CONTROLLER_PARTS, classify

    on_pmu = "ControllerNode._on_pmu (nni_battery_controller/controller_node.py:60)"
    stacks = (f"run_node (nni_msgs_adapter/ros/node_main.py:180);{on_pmu};PlantReaders.newest_clock_ns "
              "(nni_battery_controller/controller_node.py:120);"
              "PolledReader.latest (nni_msgs_adapter/ros/loop_node.py:80) 4\n"
              f"run_node (nni_msgs_adapter/ros/node_main.py:180);{on_pmu};StampedPublisher.publish "
              "(nni_msgs_adapter/ros/loop_node.py:48) 6\n")
    assert classify(stacks, CONTROLLER_PARTS) == {"/diagnostics and /clock readers": 4,
                                                 "publish: commands and controller states": 6}


@pytest.mark.parametrize(("added_ms", "verdict"), [(0.6, "met."), (1.2, "**not met**.")])
def test_the_c37118_path_is_judged_on_the_p50_it_adds_at_50_per_s(added_ms, verdict):
    text = page({"c37118-loop": c37118_loop_result(added_ms)})
    rounds = ", ".join([f"{added_ms:.2f}"] * 3)
    assert f"Added p50: **{added_ms:.3f} ms** ({rounds}) <= 1 ms: {verdict}" in text
    assert f"| C37.118 (`c37118/pmu`) | {0.3 + added_ms:.3f} / 0.800 / 1.50 | 1 | 1500 |" in text


def test_the_command_authentication_row_sets_sign_and_verify_beside_the_bare_publish():
    text = page({"command-auth": COMMAND_AUTH})
    assert "median of 15 batches of 2000 messages" in text
    assert ("| message | bare publish (µs) | sign (µs) | sealed publish (µs) | added by the seal (µs) | verify (µs) |"
            in text)
    assert "| 12.50 | 3.25 | 16.00 | +3.50 | 4.50 |" in text


@pytest.mark.parametrize(("p99_ms", "verdict"), [(3.0, "met."), (5.0, "**not met**.")])
def test_the_c37118_server_is_reported_beside_its_floor_and_judged_on_its_reporting_p99(p99_ms, verdict):
    text = page({"c37118-server": c37118_server_result(p99_ms)})
    assert "| 10 | 416 | 5.0 | 6.0 | 100000 | 40000 | 0.40 |" in text
    assert "| 52 | 2096 | 5.0 | 6.0 | 100000 | 40000 | 0.40 |" in text
    assert f"| 1500 / 1500 | 0.700 | {p99_ms:.3f} | 6.00 | 0.200 / 1.500 | 0 |" in text
    assert f"p99 **{p99_ms:.3f} ms** < 5 ms (C37.118.1 P class allows 2/Fs = 40 ms): {verdict}" in text


def test_a_c37118_server_run_that_could_not_complete_is_reported_beside_the_rows_that_did():
    run = c37118_server_result(3.0)
    run["rows"][2] = {"stations": 52, "error": "the server dropped frames"}
    run["latency"] = {"error": "the PDC process did not turn data on"}
    text = page({"c37118-server": run})
    assert "| 52 | **not completed**: the server dropped frames | | | | | |" in text
    assert "| 10 | 416 | 5.0 |" in text
    assert "Reporting latency: **not completed**: the PDC process did not turn data on" in text
    assert "P class" not in text


def test_the_network_realtime_section_states_its_rounds_and_their_length():
    """Issue 23 judges realtime on 3 rounds of 30 s: the page says how long each round ran, not a total."""
    assert "per deployment 3 alternating round(s) of 30 s: the loop" in page(results())


@pytest.mark.parametrize("cluster_wall_s, idle_s, verdicts", [
    (40.0, 0.5, ("1.90x the serial path >= 1.8x: met", "task overhead 1.2 % < 5 %: met")),
    (45.0, 4.0, ("1.69x the serial path >= 1.8x: **not met**", "task overhead 8.9 % < 5 %: **not met**")),
])
def test_the_screen_is_judged_on_its_speed_up_and_its_task_overhead(cluster_wall_s, idle_s, verdicts):
    text = page({"screening": screening_result(cluster_wall_s, idle_s)})
    for words in verdicts:
        assert words in text
    assert "the IEEE 39 N-1 screen in 119 s < 600 s: met" in text
    assert "ANDES not run (a --quick run)" in text


def test_the_screens_bisection_is_set_beside_andes_as_a_ratio():
    andes = {"cct_s": 0.153, "runs": 10, "s": 60.0}
    text = page({"screening": screening_result(40.0, 0.5, andes)})
    assert "ours 0.50 s (CCT 0.153" in text and "ANDES 2.0 60.0 s (10 runs" in text
    assert "ANDES / ours = **120x**" in text


@pytest.mark.parametrize(("stalled", "words"), [(0.9, "0.90 (within the noise: it costs the loop nothing measurable)"),
                                                (1.3, "1.30 (**beyond the noise**)")])
def test_the_never_reading_client_is_judged_against_a_reading_one_and_the_noise(stalled, words):
    text = page({"foxglove": foxglove_result(stalled=stalled)})
    assert f"The never-reading client: {words}" in text
    assert "| a client that never reads, beside one that reads | 16.0 / " in text
    assert "Streaming itself: 1.50 (**beyond the noise**" in text


def law_comparison_result(ieee39_s: float, scipy_cct: float = 0.187) -> dict:
    return {"argv": "--compare-laws --b 0 0.2 0.3 inf --duration 10", "ours_s": 8.0, "roa_s": 2.0,
            "trajectories_s": 6.0, "trajectories": 360,
            "scipy_s": 4.0, "scipy_runs": 51, "per_trajectory_ms": 78.4, "ours_per_trajectory_ms": 16.7,
            "scipy_extrapolated_s": 28.2, "checked": [{"law": "nni", "scipy_cct_s": scipy_cct, "ours": "0.187",
                                                     "runs": 17}],
            "networks": {"ieee39": {"wall_s": ieee39_s, "args": "--case ieee39 --compare-laws", "error": None}}}


@pytest.mark.parametrize("ieee39_s, scipy_cct, verdicts", [
    (26.0, 0.187, ("IEEE 39's 26 s < 300 s: met", "the baseline's CCTs equal ours: met")),
    (320.0, 0.188, ("IEEE 39's 320 s < 300 s: **not met**", "the baseline's CCTs equal ours: **not met**")),
])
def test_the_law_comparison_is_set_beside_scipy_and_judged_on_its_wall_times(ieee39_s, scipy_cct, verdicts):
    text = page({"law-comparison": law_comparison_result(ieee39_s, scipy_cct)})
    assert "| 8.00 | 2.00 | 360 | 16.7 | 78.4 | 28 | 4.7x |" in text
    assert "the SMIB comparison 8.0 s < 60 s: met" in text
    for words in verdicts:
        assert words in text


def test_a_rerun_of_some_benchmarks_replaces_only_their_sections_and_says_so():
    earlier = page({key: value for key, value in results().items() if key != "law-comparison"})
    rerun = page({"law-comparison": law_comparison_result(26.0), "roa": results()["roa"]})
    spliced = splice(earlier, rerun, "bench/run_all --only roa law-comparison", "2026-02-02 00:00 UTC")
    places = [spliced.index(heading) for heading in HEADINGS]
    assert places == sorted(places)  # every earlier section kept, in order, the new one after them
    assert all(f"\n\n{heading}" in spliced for heading in HEADINGS[1:])  # each after a blank line
    assert spliced.count("> Rerun alone by `bench/run_all --only roa law-comparison` on 2026-02-02 00:00 UTC") == 2
    untouched = earlier[earlier.index(HEADINGS[0]):earlier.index(HEADINGS[3])]
    assert untouched in spliced
    assert spliced.startswith(earlier[:earlier.index(HEADINGS[0])])  # the earlier head and machine section
