"""The machine recorded beside figures: its CPU, versions and OpenGL renderer."""

from __future__ import annotations

from sim.machine import cpu_model, describe, machine_info, machines_line

CPUINFO = """processor\t: 0
vendor_id\t: GenuineIntel
model name\t: Intel(R) Xeon(R) Platinum 8480+
flags\t\t: fpu avx2 avx512f

processor\t: 1
model name\t: Intel(R) Xeon(R) Platinum 8480+
"""


def test_cpu_model_reads_the_model_name(tmp_path):
    p = tmp_path / "cpuinfo"
    p.write_text(CPUINFO)
    assert cpu_model(p) == "Intel(R) Xeon(R) Platinum 8480+"
    # no such file (not Linux): what the platform module knows, never empty
    assert cpu_model(tmp_path / "missing")


def test_machine_info_names_the_cpu_and_the_versions():
    import cv2
    import numpy as np

    m = machine_info()
    assert m["cpus"] >= 1 and m["cpu"] and m["os"] and m["python"].count(".") == 2
    assert (m["numpy"], m["opencv"]) == (np.__version__, cv2.__version__)


def test_describe_and_the_runs_sentence():
    m = {"cpu": "AMD EPYC", "cpus": 2, "gl_renderer": "llvmpipe (LLVM 15.0.6, 256 bits)",
         "gl_version": "4.5 (Core Profile) Mesa 22.3.6"}  # fmt: skip
    assert describe(m) == (
        "AMD EPYC (2 CPUs), llvmpipe (LLVM 15.0.6, 256 bits), OpenGL 4.5 (Core Profile) Mesa 22.3.6"
    )
    assert describe({"cpu": "AMD EPYC", "cpus": 2}) == "AMD EPYC (2 CPUs)"
    assert describe({"cpu": "AMD EPYC", "cpus": 1}) == "AMD EPYC (1 CPU)"  # a one-core bench
    assert describe(None) == "not recorded"
    assert machines_line({"cpu": "X", "cpus": 4}, [m]) == (
        f"Jobs run on X (4 CPUs). Drives rendered on {describe(m)}."
    )
    assert machines_line({"cpu": "X", "cpus": 4}, []).endswith("rendered on machines not recorded.")
    assert machines_line(None, None) == "The run does not record its machines."


def test_machine_key_is_the_same_for_the_same_machine_whatever_the_key_order():
    from sim.machine import machine_key

    a = {"cpu": "X", "cpus": 2, "gl_renderer": "llvmpipe (LLVM 15.0.6, 256 bits)"}
    b = dict(reversed(list(a.items())))
    assert machine_key(a) == machine_key(b)
    assert machine_key(a) != machine_key({**a, "gl_renderer": "llvmpipe (LLVM 15.0.6, 512 bits)"})
