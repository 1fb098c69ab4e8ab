"""BENCHMARKS.md: the page's head and machine section, then each benchmark's section (written beside its benchmark)."""

from __future__ import annotations

from bench.c37118_loop import c37118_loop_section
from bench.command_auth import command_auth_section
from bench.foxglove import foxglove_section
from bench.c37118_server import c37118_server_section
from bench.latency import latency_section, share_section
from bench.law_comparison import law_comparison_section
from bench.lockstep import lockstep_section
from bench.machine import machine_section
from bench.network_lockstep import network_lockstep_section
from bench.network_profile import network_profile_section
from bench.network_realtime import network_realtime_section
from bench.roa import roa_section
from bench.screening import large_screens_section, screening_section

#: The page's sections in order: the key of a run's results each reports, and the function that writes it.
SECTIONS = (("latency", latency_section), ("controller-share", share_section), ("lockstep", lockstep_section),
            ("roa", roa_section), ("network-lockstep", network_lockstep_section),
            ("network-realtime", network_realtime_section), ("network-profile", network_profile_section),
            ("c37118-loop", c37118_loop_section), ("command-auth", command_auth_section),
            ("c37118-server", c37118_server_section), ("screening", screening_section), ("foxglove", foxglove_section),
            ("law-comparison", law_comparison_section), ("screening-large", large_screens_section))


def report(command: str, machine: dict, quick: bool, results: dict, started: str, wall_s: float) -> str:
    """The page from a run's ``results`` (section key -> what its benchmark returned; a key left out, no section)."""
    lines = ["# Benchmarks", "",
             f"Written by `{command}` on {started} (whole run {wall_s:.0f} s of wall time). "
             "Every table sets a measurement beside a baseline taken in the same run; the targets are issue 5's "
             "(sections 1-3), issue 23's (sections 4-5; issue 14 built them), issue 22's (sections 8 and 10), issue 33's "
             "(section 11), issue 34's (section 12), issue 32's (section 13) and issue 33's (section 14).", ""]
    if quick:
        lines += ["> **`--quick` run**: shortened durations for development, not the numbers to publish.", ""]
    lines += machine_section(machine)
    for key, section in SECTIONS:
        if results.get(key):
            lines += section(results[key])
    return "\n".join(lines)


def _sections(text: str) -> tuple[list[str], dict[str, list[str]]]:
    """A page's lines before its first numbered section, and its numbered sections (``## 3.`` -> lines)."""
    head, sections, current = [], {}, None
    for line in text.splitlines():
        if line.startswith("## ") and line[3:].split(".")[0].isdigit():
            current = line[3:].split(".")[0]
            sections[current] = []
        (head if current is None else sections[current]).append(line)
    return head, sections


def splice(old: str, new: str, command: str, started: str) -> str:
    """``old`` (the page of an earlier run) with each numbered section of ``new`` (a run of some benchmarks) in
    place of its namesake, or after the others if ``old`` lacks it; each such section says it was rerun alone,
    when and by what. The page's head and machine section stay ``old``'s (the run that wrote the rest)."""
    head, sections = _sections(old)
    _, fresh = _sections(new)
    for number, lines in fresh.items():
        sections[number] = [lines[0], "", f"> Rerun alone by `{command}` on {started}; the other sections are "
                                          "the earlier run's.", *lines[1:]]
    ordered = sorted(sections, key=int)
    for number in ordered:  # a page's last section lost its closing blank line to splitlines()
        if sections[number][-1] != "":
            sections[number].append("")
    return "\n".join(head + [line for number in ordered for line in sections[number]])
