#!/usr/bin/env python3
"""loss_estimator over real DDS against a bare rclpy echo node, measured the same way.

A driver publishes motor torque + speed (and output torque + speed) at a fixed sample rate; the
system under test (SUT) answers on ``/rollergear/loss/torque``.  For each SUT and rate: dropped
samples, input-to-output latency (last input of a sample -> its output; the k-th output answers the
k-th sample), and the SUT's CPU use.  Then the highest sustained loss-free rate of each.
With ``--stamped`` loss_estimator publishes only its stamped estimate (``node.publish_float64:=false``:
one ``sensor_msgs/JointState`` per sample on ``loss/estimate`` instead of four Float64) and is timed
on that topic; the echo node still answers four messages with four.
With ``--memory`` the baseline is loss_estimator itself, against loss_estimator with a memoryless
``drag_constant`` and with the ``dahl`` effect on (a state stepped every sample), both adapted online
(``estimator.adapt``): the cost of adapting an effect, and what a memory adds to it.
With ``--tracing`` loss_estimator without its online tracer (``node.trace:=false``) against it
tracing back to back (``node.trace_period_s:=1``: the worker process is busy throughout, and the
node copies its buffer for each trace): the cost of tracing to the input path.
With ``--estimator-only`` no DDS: the estimator each loss_estimator runs, fed the driver's messages
in-process (what the node adds to rclpy's per-message cost), in µs per sample.
With ``--cpu-at RATE`` no ramp: each system under test takes ``RATE`` samples/s for ``--seconds``,
``--repeat`` times interleaved, and its CPU time per sample is compared.  On its own core (``--pin``) a
node's highest loss-free rate is what its CPU time per sample allows, and CPU time is what a busy
machine disturbs least, so this resolves differences of a few percent that the ramp (±30 % between
runs here) cannot: the ratio printed is the rate it implies, ``CPU per sample of the baseline / of this``.
Usage: python bench/bench_node.py [--seconds 5] [--repeat 3] [--pin] [--no-outputs] [--stamped] [--memory]
                                  [--tracing] [--estimator-only [--multirate]] [--cpu-at RATE]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        parts = fh.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


#: ``--tracing``: the node without its online tracer, and with it tracing back to back (a trace of the
#: last window started each second: the worker is busy throughout the measurement)
TRACING = {"loss_estimator-untraced": ("node.trace:=false",),
           "loss_estimator+tracing": ("node.trace:=true", "node.trace_period_s:=1.0", "node.accept_traced:=off")}
#: ``--memory``: the effect each system under test has on (adapted online like any accepted effect)
EFFECT_ON = {
    "loss_estimator+drag_constant": ("effects.drag_constant.enabled:=true", "effects.drag_constant.c_nm:=0.05"),
    "loss_estimator+dahl": ("effects.dahl.enabled:=true", "effects.dahl.c_nm:=0.05",
                            "effects.dahl.presliding_rad:=0.01"),
}


def estimator_cost_us(kind: str, samples: int = 60_000, with_outputs: bool = True, speed_every: int = 1) -> float:
    """µs per sample of the estimator ``kind``'s node runs (arrival pairing, as the events executor),
    fed the driver's four messages per sample in-process: pairing, model, effects, adaptation;
    ``speed_every``: the speed only with every n-th sample (a channel at a tenth of the torque's
    rate: resampled onto its stamps, :mod:`core.resample`)."""
    from rollergear_ros.core.estimator import Estimator
    from rollergear_ros.core.pairing import OUT_SPEED, OUT_TORQUE, SPEED, TORQUE
    from rollergear_ros.core.params import load_config

    overrides = dict(arg.split(":=") for arg in EFFECT_ON.get(kind, ()))
    config = load_config(ROOT / "config" / "gearbox.yaml",
                         {k: (True if v == "true" else float(v)) for k, v in overrides.items()})
    push = Estimator(config, "arrival").push
    t = 1_000_000_000
    t0 = time.perf_counter()
    for k in range(samples):
        t += 100_000
        push(TORQUE, t, 10.0 + k % 50)
        if k % speed_every == 0:
            push(SPEED, t + 1, 100.0 + k % 7)
        if with_outputs:
            push(OUT_TORQUE, t + 2, 13.0 + k % 50)
            push(OUT_SPEED, t + 3, 73.0)
    return (time.perf_counter() - t0) / samples * 1e6


def mean_interval(ratios: list[float]) -> str:
    """The runs' mean ratio and its 95 % interval (Student's t over the runs), as text."""
    from scipy import stats

    r = np.asarray(ratios, dtype=float)
    if len(r) < 2:
        return ""
    half = stats.t.ppf(0.975, len(r) - 1) * r.std(ddof=1) / np.sqrt(len(r))
    return f"; mean {r.mean():.3f}, 95 % interval {r.mean() - half:.3f}-{r.mean() + half:.3f}"


def start_sut(kind: str, executor: str, cpu: int | None = None, stamped: bool = False,
              baseline_tree: Path | None = None) -> subprocess.Popen:
    """A system under test: the echo node, loss_estimator (with an effect on, for the ``EFFECT_ON``
    kinds), or ``baseline``: loss_estimator of another source tree (``--against``)."""
    env = None
    if kind == "echo":
        cmd = [sys.executable, str(ROOT / "bench" / "echo_node.py"), executor]
    else:
        tree = baseline_tree if kind == "baseline" else ROOT
        # the tree's node module: in the ros wing, or (code before the wings) at the package's top
        module = "rollergear_ros.ros.node" if (tree / "rollergear_ros" / "ros" / "node.py").exists() \
            else "rollergear_ros.node"
        cmd = [sys.executable, "-m", module, "--ros-args", "--params-file",
               str(tree / "config" / "gearbox.yaml"), "-p", f"node.executor:={executor}"]
        if stamped:
            cmd += ["-p", "node.publish_float64:=false"]
        cmd += [arg for value in EFFECT_ON.get(kind, TRACING.get(kind, ())) for arg in ("-p", value)]
        if kind == "baseline":
            env = {**os.environ, "PYTHONPATH": str(tree)}
    pin = (lambda: os.sched_setaffinity(0, {cpu})) if cpu is not None else None
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=pin,
                            env=env, cwd=str(baseline_tree) if kind == "baseline" else None)


def run(driver, sut: subprocess.Popen, rate: float, seconds: float, with_outputs: bool) -> dict:
    from std_msgs.msg import Float64

    node, pubs, received = driver
    received.clear()
    n = int(rate * seconds)
    send_ns = np.zeros(n, dtype=np.int64)
    period = 1e9 / rate
    cpu0 = cpu_seconds(sut.pid)
    t_start = time.monotonic_ns() + 50_000_000
    msg = Float64()
    for k in range(n):
        target = t_start + int(k * period)
        while True:
            wait = target - time.monotonic_ns()
            if wait <= 0:
                break
            time.sleep(wait * 1e-9 if wait > 1_000_000 else 0)
        msg.data = 10.0 + (k % 50)
        for i, p in enumerate(pubs):
            if i >= 2 and not with_outputs:
                break
            if i == 1:
                msg.data = 100.0
            elif i == 2:
                msg.data = 13.0 + (k % 50)
            elif i == 3:
                msg.data = 73.0
            p.publish(msg)
        send_ns[k] = time.monotonic_ns()
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and len(received) < n:
        time.sleep(0.01)
    cpu = cpu_seconds(sut.pid) - cpu0
    recv = np.array(received[:n], dtype=np.int64)
    lat = (recv - send_ns[:len(recv)]) * 1e-3 if len(recv) else np.array([np.nan])
    achieved = (n - 1) / max((send_ns[-1] - send_ns[0]) * 1e-9, 1e-9)
    return {"sent": n, "received": len(received), "dropped": n - min(len(received), n), "achieved": achieved,
            "p50_us": float(np.percentile(lat, 50)), "p99_us": float(np.percentile(lat, 99)),
            "cpu_pct": 100.0 * cpu / (n / rate)}


def loss_free(
    driver, sut: subprocess.Popen, rate: float, seconds: float, with_outputs: bool
) -> tuple[bool, float, bool]:
    """Whether ``rate`` is sustained without a drop: one transient drop (a scheduling hiccup on
    this 2-core machine) earns a second try, two mean no.  Returns (ok, achieved rate, driver-bound)."""
    for _ in range(2):
        r = run(driver, sut, rate, seconds, with_outputs)
        if r["achieved"] < 0.9 * rate:  # the Python driver cannot publish faster
            return False, r["achieved"], True
        if r["dropped"] == 0:
            return True, r["achieved"], False
    return False, r["achieved"], False


def max_loss_free_rate(
    driver, sut: subprocess.Popen, with_outputs: bool, seconds: float = 3.0, ceiling: float = 20000.0,
    step: float = 1000.0,
) -> tuple[float, bool]:
    """Highest rate with no dropped sample: ramp in ``step`` samples/s steps until a rate fails (see
    :func:`loss_free`), then bisect three times (resolution ``step``/8: 125 samples/s by default).
    Also says whether the driver could not keep up.  A system still loss-free at ``ceiling`` is
    reported at it: raise the ceiling on a machine where both systems reach it."""
    good = 0.0
    rate = step
    while rate <= ceiling:
        ok, achieved, driver_bound = loss_free(driver, sut, rate, seconds, with_outputs)
        if driver_bound:
            return good, True
        if not ok:
            break
        good = achieved
        rate += step
    else:
        return good, False
    lo, hi = rate - step, rate
    for _ in range(3):
        mid = (lo + hi) / 2
        ok, achieved, _ = loss_free(driver, sut, mid, seconds, with_outputs)
        if ok:
            lo, good = mid, achieved
        else:
            hi = mid
    return good, False


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--no-outputs", action="store_true", help="publish only motor torque and speed")
    ap.add_argument(
        "--executor",
        choices=("events", "single_threaded"),
        default="events",
        help="rclpy executor of both systems under test",
    )
    ap.add_argument("--repeat", type=int, default=3, help="interleaved runs of each system (median ratio)")
    ap.add_argument("--stamped", action="store_true",
                    help="loss_estimator publishes only its stamped estimate (one message per sample)")
    ap.add_argument("--memory", action="store_true",
                    help="loss_estimator with the dahl effect on against loss_estimator without it")
    ap.add_argument(
        "--pin",
        action="store_true",
        help="driver on CPU 0, system under test on CPU 1 (so they do not compete for a core)",
    )
    ap.add_argument("--ceiling", type=float, default=20000.0, help="highest rate tried [samples/s]")
    ap.add_argument("--step", type=float, default=1000.0, help="the ramp's step [samples/s]")
    ap.add_argument("--against", type=Path, metavar="TREE",
                    help="also run loss_estimator of another source tree (e.g. a worktree of the previous main), "
                         "interleaved, and print this tree's rate over its")
    ap.add_argument("--tracing", action="store_true",
                    help="loss_estimator tracing back to back (node.trace_period_s:=1) against it without tracing")
    ap.add_argument("--estimator-only", action="store_true",
                    help="no DDS: the estimator of each loss_estimator in-process, µs per sample")
    ap.add_argument("--multirate", action="store_true",
                    help="with --estimator-only: the speed at a tenth of the torque's rate against paired channels")
    ap.add_argument("--cpu-at", type=float, metavar="RATE",
                    help="no ramp: CPU time per sample of each system at RATE samples/s (the rate it implies)")
    args = ap.parse_args()
    if args.estimator_only and args.multirate:
        costs = {1: [], 10: []}
        for _ in range(args.repeat):
            for every in costs:
                costs[every].append(estimator_cost_us("loss_estimator", with_outputs=not args.no_outputs,
                                                      speed_every=every))
        paired, multi = np.median(costs[1]), np.median(costs[10])
        print(f"paired channels:          {', '.join(f'{c:.1f}' for c in costs[1])} µs per sample")
        print(f"speed at 1/10 the rate:   {', '.join(f'{c:.1f}' for c in costs[10])} µs per sample")
        print(f"rate with the speed resampled / paired: {paired / multi:.3f}x (target >= 0.95)")
        return
    if args.estimator_only:
        kinds = ("loss_estimator", *EFFECT_ON) if args.memory else ("loss_estimator",)
        costs = {k: [] for k in kinds}
        for _ in range(args.repeat):
            for k in kinds:
                costs[k].append(estimator_cost_us(k, with_outputs=not args.no_outputs))
        for k in kinds:
            print(f"{k:28s} estimator without DDS: {', '.join(f'{c:.1f}' for c in costs[k])} µs per sample")
        return
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
    if args.pin:
        os.sched_setaffinity(0, {0})
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from rollergear_ros.ros.qos import output_qos
    from rollergear_ros.base.output_channels import OUTPUT_CHANNELS

    OUTPUT_QOS = output_qos(OUTPUT_CHANNELS["loss_torque"])

    rclpy.init()
    node = Node("bench_driver")
    pubs = [
        node.create_publisher(Float64, f"/rollergear/{t}", 1000)
        for t in ("motor/torque", "motor/speed", "output/torque", "output/speed")
    ]
    received: list[int] = []
    estimate = "/rollergear/loss/estimate" if args.stamped else "/rollergear/loss/torque"
    answer = ({"echo": "/rollergear/loss/torque", "loss_estimator": estimate, "baseline": estimate}
              | dict.fromkeys(EFFECT_ON, estimate) | dict.fromkeys(TRACING, estimate))
    node.create_subscription(
        Float64, "/rollergear/loss/torque", lambda raw: received.append(time.monotonic_ns()), OUTPUT_QOS, raw=True
    )
    if args.stamped:
        node.create_subscription(JointState, answer["loss_estimator"], lambda raw: received.append(time.monotonic_ns()),
                                 OUTPUT_QOS, raw=True)
    ex = EventsExecutor()
    ex.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            ex.spin_once(timeout_sec=0.05)

    th = threading.Thread(target=spin, daemon=True)
    th.start()
    driver = (node, pubs, received)
    with_outputs = not args.no_outputs
    kinds = (("loss_estimator", *EFFECT_ON) if args.memory else tuple(TRACING) if args.tracing
             else ("echo", "loss_estimator"))
    if args.against is not None:
        kinds = ("loss_estimator", "baseline") if args.cpu_at else (*kinds, "baseline")
    best_of: dict[str, list[float]] = {k: [] for k in kinds}
    p99_of: dict[str, list[float]] = {k: [] for k in kinds}
    for rep in range(args.repeat):
        for kind in kinds if rep % 2 == 0 else kinds[::-1]:  # interleaved: drifts hit all alike
            sut = start_sut(kind, args.executor, 1 if args.pin else None, args.stamped, args.against)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and (
                pubs[0].get_subscription_count() == 0 or node.count_publishers(answer[kind]) == 0
            ):
                time.sleep(0.05)
            time.sleep(1.0)
            run(driver, sut, 200, 1.0, with_outputs)  # warm-up
            if args.cpu_at:
                r = run(driver, sut, args.cpu_at, args.seconds, with_outputs)
                sut.send_signal(signal.SIGINT)
                sut.wait(timeout=20)
                cpu_us = r["cpu_pct"] / 100.0 / args.cpu_at * 1e6  # CPU seconds per second over samples per second
                best_of[kind].append(cpu_us)
                print(f"run {rep + 1} {kind:28s} {args.cpu_at:.0f} samples/s: dropped {r['dropped']}/{r['sent']}, "
                      f"CPU {cpu_us:.1f} µs per sample", flush=True)
                continue
            r1k = run(driver, sut, 1000, args.seconds, with_outputs)
            best, driver_bound = max_loss_free_rate(driver, sut, with_outputs, ceiling=args.ceiling, step=args.step)
            sut.send_signal(signal.SIGINT)
            sut.wait(timeout=20)
            best_of[kind].append(best)
            p99_of[kind].append(r1k["p99_us"] if r1k["dropped"] == 0 else float("nan"))
            at_ceiling = best >= args.ceiling - args.step / 8
            print(
                f"run {rep + 1} {kind:28s} 1 kHz: dropped {r1k['dropped']}/{r1k['sent']}, latency p50 "
                f"{r1k['p50_us']:.0f} µs, p99 {r1k['p99_us']:.0f} µs, CPU {r1k['cpu_pct']:.0f} % of a core per "
                f"1 k samples/s; max loss-free rate {best:.0f} samples/s"
                + (" (driver-bound: the publisher could not go faster)" if driver_bound else "")
                + (" (at the ceiling: raise --ceiling)" if at_ceiling else ""),
                flush=True,
            )
    stop.set()
    th.join()
    channels = 4 if with_outputs else 2
    pairs = ([(kinds[0], kinds[1], None), (kinds[0], kinds[2], 0.9), (kinds[1], kinds[2], 0.9)] if args.memory
             else [(kinds[0], kinds[1], 0.9)] if args.tracing
             else [(kinds[0], kinds[1], 1.0 if args.stamped else 0.8)])
    if args.against is not None:
        pairs.append(("baseline", "loss_estimator", None))
    print(f"executor: {args.executor}{'; driver on CPU 0, SUT on CPU 1' if args.pin else ''}"
          f"{'; loss_estimator publishes only the stamped estimate' if args.stamped else ''}; inputs per sample: "
          f"{channels} topics")
    if args.cpu_at:  # the rate a CPU time per sample implies: baseline's over this one's
        if args.against is not None:
            pairs = [("baseline", "loss_estimator", 0.95)]
        for base, sut, target in pairs:
            ratios = [b / c for c, b in zip(best_of[sut], best_of[base])]
            print(f"{sut} CPU per sample: {', '.join(f'{c:.1f}' for c in best_of[sut])} µs; {base}: "
                  f"{', '.join(f'{c:.1f}' for c in best_of[base])} µs -> the rate they imply, {sut} / {base} per "
                  f"run: {', '.join(f'{r:.3f}' for r in ratios)}; median {float(np.median(ratios)):.3f}"
                  + (f" (target >= {target})" if target else "") + mean_interval(ratios))
        rclpy.shutdown()
        return
    for base, sut, target in pairs:
        ratios = [lo / e if e else float("nan") for lo, e in zip(best_of[sut], best_of[base])]
        print(f"{sut} max rate / {base} max rate per run: {', '.join(f'{r:.2f}' for r in ratios)}; "
              f"median {float(np.median(ratios)):.2f}" + (f" (target >= {target})" if target else ""))
    if args.tracing:  # 1 kHz latency with a trace under way against without (NaN: a run that dropped samples)
        ratios = [t / u for t, u in zip(p99_of[kinds[1]], p99_of[kinds[0]])]
        print(f"{kinds[1]} 1 kHz p99 / {kinds[0]} 1 kHz p99 per run: {', '.join(f'{r:.2f}' for r in ratios)}; "
              f"median {float(np.median(ratios)):.2f} (target <= 1.5)")
    rclpy.shutdown()


if __name__ == "__main__":
    main()
