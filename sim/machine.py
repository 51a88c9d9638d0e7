"""The machine a figure was measured on: its CPU, the software versions and the OpenGL
renderer.

Renders are bit-identical on one machine but not across machines (llvmpipe compiles its
shaders for the CPU it runs on: docs/DESIGN.md, "Reading the figures"), and run times
depend on the CPU. Drives (``manifest.json``), suite runs (``run.json``) and benchmarks
record the machine beside their figures.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import cv2
import numpy as np

# the OpenGL context's GL_RENDERER and GL_VERSION, noted when this process first made one
# (`note_gl_context`); None before
_gl: dict[str, str] | None = None


def cpu_model(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU's model name (Linux: /proc/cpuinfo), else what `platform` knows."""
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def note_gl_context() -> None:
    """Note the current OpenGL context's renderer and version (once per process; call
    with a context current)."""
    global _gl
    if _gl is not None:
        return
    from OpenGL import GL

    def text(name: int) -> str:
        s = GL.glGetString(name)
        return s.decode(errors="replace") if isinstance(s, bytes) else str(s)

    _gl = {"gl_renderer": text(GL.GL_RENDERER), "gl_version": text(GL.GL_VERSION)}


def gl_info() -> dict[str, str] | None:
    """{"gl_renderer", "gl_version"} of the context this process rendered with, or None."""
    return None if _gl is None else dict(_gl)


def machine_info() -> dict[str, object]:
    """What the figures of this process depend on: cpu (model), cpus (logical CPUs this
    process may use), os, python, numpy, opencv; gl_renderer and gl_version once it has
    rendered."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 0
    return {
        "cpu": cpu_model(),
        "cpus": cpus,
        "os": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        **(gl_info() or {}),
    }


def machine_key(machine: dict) -> str:
    """A machine (`machine_info`) as a string: equal for the same machine and software."""
    return json.dumps(machine, sort_keys=True)


def describe(machine: dict | None) -> str:
    """One line naming a machine (`machine_info`): CPU, CPUs and OpenGL renderer."""
    if not machine:
        return "not recorded"
    n = machine.get("cpus", "?")
    text = f"{machine.get('cpu', 'unknown CPU')} ({n} CPU{'' if n == 1 else 's'})"
    if machine.get("gl_renderer"):
        text += f", {machine['gl_renderer']}, OpenGL {machine.get('gl_version', '?')}"
    return text


def machines_line(machine: dict | None, render_machines: list[dict] | None) -> str:
    """One sentence naming where a suite run's figures come from: the machine that ran its
    jobs (``machine``) and those that rendered its drives (``render_machines``)."""
    if not machine:
        return "The run does not record its machines."
    drawn = "; ".join(describe(m) for m in render_machines or []) or "machines not recorded"
    return f"Jobs run on {describe(machine)}. Drives rendered on {drawn}."
