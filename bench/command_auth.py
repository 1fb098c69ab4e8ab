"""Section 9: the cost of authenticated battery commands and measurements per sample (HMAC-SHA256 seal and check) beside the bare
publish of the same command; with its report section."""

from __future__ import annotations

import statistics
import time

from bench.common import progress

#: Commands per timed batch, and batches per measurement (the median batch is reported).
BATCH, BATCHES = 2000, 15


def _per_sample_us(work, count: int) -> float:
    """The median over BATCHES of ``work(count)``'s wall time per sample, µs."""
    times = []
    for _ in range(BATCHES):
        started = time.perf_counter_ns()
        work(count)
        times.append((time.perf_counter_ns() - started) / count / 1e3)
    return statistics.median(times)


def bench_command_auth(domain_id: int) -> dict:
    """Per sample, in one process: the bare command's pack and publish (rclpy, the contract's QoS, no reader); the
    controller's seal (sign) and the sealed pack and publish; the plant's read of the sealed bytes and its check."""
    import rclpy
    from rclpy.context import Context

    from nni_msgs_adapter.ros import command_auth, contract

    progress("command authentication: sign and verify per sample")
    key, topic = bytes(range(command_auth.KEY_BYTES)), "/bench/battery/command"
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node("bench_command_auth", context=context)
    try:
        publisher = node.create_publisher(*contract.endpoint(contract.TOPIC_BATTERY_COMMAND, "bench"))
        bare, sealed = contract.command_bytes(), contract.command_bytes(sealed=True)
        signer = command_auth.CommandSigner(key, topic, 0)
        samples = [sealed.pack(k, 0.1, signer.seal(k, 0.1)) for k in range(BATCH)]

        def publish_bare(count):
            for k in range(count):
                publisher.publish(bare.pack(k, 0.1))

        def sign(count):
            for k in range(count):
                signer.seal(k, 0.1)

        def publish_sealed(count):
            for k in range(count):
                publisher.publish(sealed.pack(k, 0.1, signer.seal(k, 0.1)))

        def verify(count):
            verifier = command_auth.CommandVerifier(key, topic)
            for data in samples[:count]:
                stamp_ns, power, seal = contract.command_from_bytes(data)
                verifier.check(seal, stamp_ns, power)

        result = {"bare_publish_us": _per_sample_us(publish_bare, BATCH), "sign_us": _per_sample_us(sign, BATCH),
                  "sealed_publish_us": _per_sample_us(publish_sealed, BATCH),
                  "verify_us": _per_sample_us(verify, BATCH), "batch": BATCH, "batches": BATCHES,
                  "measurement": _measurement_costs(node, key)}
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return result


def _measurement_costs(node, key: bytes) -> dict:
    """The same four for a plant's measurement (``pmu``: stamp, angle, speed, P_E; its seal carries the mode flag),
    as the plant seals it and the controller checks it (issue 31)."""
    from nni_msgs_adapter.ros import command_auth, contract

    topic = "/bench/pmu"
    publisher = node.create_publisher(*contract.endpoint(contract.TOPIC_PMU, "bench"))
    bare, sealed = contract.layout(contract.TOPIC_PMU), contract.layout(contract.TOPIC_PMU, sealed=True)
    signer = command_auth.Signer(key, topic, "measurement", 0)
    flag = command_auth.LOCKSTEP_FLAG
    samples = [sealed.pack(k, 0.2, 0.0, 0.8, signer.seal(k, 0.2, 0.0, 0.8, flag=flag)) for k in range(BATCH)]

    def publish_bare(count):
        for k in range(count):
            publisher.publish(bare.pack(k, 0.2, 0.0, 0.8))

    def sign(count):
        for k in range(count):
            signer.seal(k, 0.2, 0.0, 0.8, flag=flag)

    def publish_sealed(count):
        for k in range(count):
            publisher.publish(sealed.pack(k, 0.2, 0.0, 0.8, signer.seal(k, 0.2, 0.0, 0.8, flag=flag)))

    def verify(count):
        verifier = command_auth.MeasurementVerifier(key, topic)
        for data in samples[:count]:
            (stamp_ns, delta, speed), efforts, seal = contract.pmu_from_bytes(data)
            verifier.check(seal, stamp_ns, delta, speed, *efforts)

    return {"bare_publish_us": _per_sample_us(publish_bare, BATCH), "sign_us": _per_sample_us(sign, BATCH),
            "sealed_publish_us": _per_sample_us(publish_sealed, BATCH), "verify_us": _per_sample_us(verify, BATCH)}


def _row(name: str, r: dict) -> str:
    added = r["sealed_publish_us"] - r["bare_publish_us"]
    return (f"| {name} | {r['bare_publish_us']:.2f} | {r['sign_us']:.2f} | {r['sealed_publish_us']:.2f} | "
            f"{added:+.2f} | {r['verify_us']:.2f} |")


def command_auth_section(r: dict) -> list[str]:
    """Section 9: what sealing and checking a command costs, beside the bare publish."""
    rows = [_row("battery command (controller -> plant)", r)]
    if "measurement" in r:
        rows.append(_row("measurement `pmu` (plant -> controller)", r["measurement"]))
    return ["## 9. Authenticated commands and measurements: sign and verify per sample", "",
            "The plant applies only commands sealed under the run's key, and the controller acts only on "
            "measurements sealed by its plant (HMAC-SHA256 over the kind, the topic, a sequence number, the stamp "
            "and the values, a measurement's mode flag too; `nni_msgs_adapter.ros.command_auth`). Measured in one "
            f"process, the median of {r['batches']} batches of {r['batch']} messages: the writer's bare "
            "publish (pack and rclpy publish, no reader), its seal alone, the sealed pack and "
            "publish, and the reader's read of the sealed bytes with the check. Per lockstep sample the plant seals "
            "a measurement and its true state, the controller checks the measurement and seals its command and "
            "its state, the plant checks the command: section 2's loop runs with all of them.", "",
            "| message | bare publish (µs) | sign (µs) | sealed publish (µs) | added by the seal (µs) | verify (µs) |",
            "|---|---:|---:|---:|---:|---:|", *rows, ""]
