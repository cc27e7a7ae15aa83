"""The numeric environment: the same floats from the same inputs on every x86-64 CPU with AVX2.

The libraries that compute our floats pick their kernels by the CPU they run on, and kernels that use
other instructions or another summation order give other last bits. A training amplifies them into
another policy (issue "Byte-identical on any x86-64 machine"). ``SRMPC_NUMERICS=pinned`` fixes each
library's code path to one that every x86-64 CPU with AVX2 and FMA runs alike, whatever its vendor,
its widest vector unit or its cache sizes:

=========================  ==========================  ==================================================
library                    variable = pinned value     what it fixes
=========================  ==========================  ==================================================
MKL (torch's BLAS, LAPACK  none: off the path          torch's ``mm``/``addmm``/``bmm``/``addmv``/``dot``,
and vector math)                                       ``linalg_qr`` and the VML functions (``exp``,
                                                       ``log``, ``tanh``, ``sqrt``, ``erf``, ...) run in
                                                       NumPy instead (:mod:`srmpc.pinned_kernels`). MKL is
                                                       not vendor-neutral: even its ``COMPATIBLE`` branch
                                                       (``MKL_CBWR``) trained other bytes on an Intel Xeon
                                                       than on an AMD EPYC
ATen (torch's own kernels) ``ATEN_CPU_CAPABILITY=avx2`` vectorized reductions and math (sigmoid, sum,
                                                       softplus): an AVX-512 CPU would take its 16-lane
                                                       kernels
oneDNN                     ``ONEDNN_MAX_CPU_ISA=AVX2`` oneDNN's JIT kernels (not on our float32 paths
                                                       today; pinned so that none appears unnoticed)
NumPy's SIMD dispatch      ``NPY_ENABLE_CPU_FEATURES`` only the AVX2 level (``X86_V3``) of NumPy's
                           ``=X86_V3``                 dispatched loops (``np.tanh``, ``np.exp``), not its
                                                       AVX-512 ones
OpenBLAS (NumPy, SciPy)    ``OPENBLAS_CORETYPE=        the Haswell (AVX2) kernels, not SkylakeX's
                           Haswell``
OpenBLAS's threads         ``OPENBLAS_NUM_THREADS=1``  one thread, so that no reduction is split by the
                                                       machine's core count (2 threads trained other bytes)
=========================  ==========================  ==================================================

Measured on an AMD EPYC with AVX-512 (``python -m pipelines.numerics_probe --caps``,
results/benchmarks/isa_caps.json): a policy's actions in numpy (``sim.mlp.MlpPolicy``'s matrix products)
gave other bytes with OpenBLAS's Haswell kernels than with its SkylakeX ones, so an AVX2 CPU evaluates the
same policy differently; a training moved with ``MKL_CBWR=AVX2``, ``=COMPATIBLE`` and
``ATEN_CPU_CAPABILITY=default``. On an Intel Xeon, MKL's vector math changed bytes with
``MKL_ENABLE_INSTRUCTIONS``, and no MKL setting gave the AMD EPYC's bytes (issue "Byte-identical on Intel and
AMD"): hence MKL off the path rather than pinned.

numba is not pinned: its code has no fast-math, so LLVM neither reassociates nor contracts, and a
training and the evaluations of a policy and of SRMPC gave the same bytes with ``NUMBA_CPU_NAME=generic``
and ``=haswell`` (isa_caps.json); a pinned target would also cost a second compilation of every kernel.
glibc's libm picks its FMA variants on every CPU with AVX2.

Each variable is read once, when its library loads, so the pin is applied when ``srmpc`` is first
imported (:func:`pin_process`, from ``srmpc/__init__.py``), before it imports numpy; the rerouted torch kernels
are registered when torch is first imported (an import hook), so a process that never trains never loads torch
for them. A process that
loaded numpy, torch, scipy or numba before importing ``srmpc`` (a benchmark script) is started again,
once, with the same command line and the pinned variables; children (evaluation workers, SLURM jobs)
inherit them. A variable the pin sets replaces the machine's own value, and ``NPY_DISABLE_CPU_FEATURES``
is removed (NumPy refuses both it and ``NPY_ENABLE_CPU_FEATURES``); both are recorded under ``replaced``.

The thread count: natively, PPO-L-SI trained on 1 and 2 threads gives other bytes (MKL's kernels follow the thread
count). Pinned, it gives the same bytes (``tests/test_golden_hashes.py``, 3 iterations): OpenBLAS runs on one
thread, and no ATen reduction on a training's path is split by thread (ATen splits a full reduction only above its
grain size, 32768 elements, and then by the thread count). A new reduction over more elements (a loss averaged over
a whole batch of 32768 frames, say) would make a training's bytes depend on ``agent.num_threads`` again, and that
test would fail.

``SRMPC_NUMERICS``: ``native`` (the libraries' own choices; today's default, under which the committed
results were made) or ``pinned``. The regeneration (issue "The study regenerated") makes ``pinned``
the default. Each run records :func:`environment_record` in its ``summary.json`` (key
:data:`SUMMARY_KEY`) and as MLflow tags; it is not part of the run's identity.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import json
import os
import platform
import sys
from importlib import metadata

MODE_VARIABLE = "SRMPC_NUMERICS"
PINNED = "pinned"
NATIVE = "native"
MODES = (PINNED, NATIVE)
DEFAULT_MODE = NATIVE
"""The mode when ``SRMPC_NUMERICS`` is unset: ``native`` until the regeneration flips it."""

PINNED_VARIABLES = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "NPY_ENABLE_CPU_FEATURES": "X86_V3",
    "OPENBLAS_CORETYPE": "Haswell",
    "OPENBLAS_NUM_THREADS": "1",
}
"""The pin: each library's variable and its value (read when the library loads)."""

CLEARED_VARIABLES = ("NPY_DISABLE_CPU_FEATURES",)
"""Removed by the pin: NumPy refuses to load with both NPY_DISABLE_ and NPY_ENABLE_CPU_FEATURES set."""

REQUIRED_CPU_FLAGS = ("avx2", "fma")
"""/proc/cpuinfo flags every pinned code path needs."""

NUMERIC_MODULES = ("numpy", "torch", "scipy", "numba")
"""Modules that load a library the pin configures: loaded before the pin, the process starts again."""

REPLACED_VARIABLE = "SRMPC_NUMERICS_REPLACED"
"""The machine's own values of the pinned variables, as JSON, passed on to the restarted process and children."""

SUMMARY_KEY = "environment"
"""The key of :func:`environment_record` in a run's ``summary.json``: compared results leave it out."""

FLOAT_LIBRARIES = ("torch", "numpy", "scipy", "numba", "llvmlite", "torchrl", "tensordict", "stable-baselines3",
                   "highway-env", "gymnasium", "piqp", "osqp", "clarabel", "proxsuite", "qpsolvers", "casadi")
"""Distributions whose versions a run records: the libraries that compute its floats."""


class NumericsError(RuntimeError):
    """The pin cannot be applied (a bad ``SRMPC_NUMERICS``, a CPU without AVX2): one line for the user."""


def requested_mode(environ: dict[str, str] | None = None) -> str:
    """``SRMPC_NUMERICS`` (or :data:`DEFAULT_MODE`); a value outside :data:`MODES` raises NumericsError."""
    value = (os.environ if environ is None else environ).get(MODE_VARIABLE, DEFAULT_MODE).strip().lower()
    if value not in MODES:
        raise NumericsError(f"{MODE_VARIABLE}={value!r}: must be one of {', '.join(MODES)}")
    return value


def cpuinfo() -> dict[str, str]:
    """The first processor's fields of ``/proc/cpuinfo`` (model name, vendor_id, cpu family, flags, ...); empty
    where there is none."""
    fields: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if not line.strip() and fields:
                    break
                key, _, value = line.partition(":")
                fields.setdefault(key.strip(), value.strip())
    except OSError:
        return {}
    return fields


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or the platform's processor string elsewhere."""
    return cpuinfo().get("model name") or platform.processor() or platform.machine()


def cpu_flags() -> set[str]:
    """The CPU's feature flags (``/proc/cpuinfo``; empty where there is none)."""
    return set(cpuinfo().get("flags", "").split())


def cpu_summary() -> dict:
    """What a measurement records of its CPU: model, vendor, family/model/stepping, machine, and whether it has
    AVX2, FMA and AVX-512F."""
    info, flags = cpuinfo(), cpu_flags()
    return {"model": cpu_model(), "vendor": info.get("vendor_id"),
            "family_model_stepping": [info.get("cpu family"), info.get("model"), info.get("stepping")],
            "machine": platform.machine(),
            **{flag: flag in flags for flag in ("avx2", "fma", "avx512f")}}


def is_pinned(environ: dict[str, str] | None = None) -> bool:
    """Whether every pinned variable holds its pinned value."""
    environ = os.environ if environ is None else environ
    return (all(environ.get(name) == value for name, value in PINNED_VARIABLES.items())
            and not any(name in environ for name in CLEARED_VARIABLES))


def pin_process() -> None:
    """Apply the requested mode to this process: with ``pinned``, set :data:`PINNED_VARIABLES` (and start
    the process again if a numeric library is already loaded), and route torch's MKL kernels to
    :mod:`srmpc.pinned_kernels` when torch loads. Raises NumericsError in one line."""
    if requested_mode() == NATIVE:
        return
    if not is_pinned():
        _set_pinned_variables()
    _route_torch_kernels()


def _set_pinned_variables() -> None:
    """Set :data:`PINNED_VARIABLES` (recording the machine's own values), and start again if a numeric library is
    loaded."""
    missing = [flag for flag in REQUIRED_CPU_FLAGS if flag not in cpu_flags()]
    if platform.machine() not in ("x86_64", "AMD64") or missing:
        raise NumericsError(f"{MODE_VARIABLE}={PINNED}: needs an x86-64 CPU with {', '.join(REQUIRED_CPU_FLAGS)}; "
                            f"this one ({cpu_model()}, {platform.machine()}) lacks {', '.join(missing) or 'x86-64'}")
    replaced = {name: os.environ[name] for name, value in PINNED_VARIABLES.items()
                if name in os.environ and os.environ[name] != value}
    replaced |= {name: os.environ.pop(name) for name in CLEARED_VARIABLES if name in os.environ}
    os.environ[REPLACED_VARIABLE] = json.dumps(replaced, sort_keys=True)
    os.environ.update(PINNED_VARIABLES)
    loaded = [name for name in NUMERIC_MODULES if name in sys.modules]
    if loaded:
        _restart(loaded)


class _RouteWhenTorchLoads(importlib.abc.MetaPathFinder):
    """An import hook: once torch's module has run, register the pinned kernels (:func:`srmpc.pinned_kernels.route`)
    before anything uses torch."""

    def find_spec(self, fullname, path, target=None):
        if fullname != "torch":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec("torch")
        if spec is None or spec.loader is None:
            return spec
        load = spec.loader.exec_module

        def exec_module(module):
            load(module)
            from srmpc import pinned_kernels

            pinned_kernels.route()

        spec.loader.exec_module = exec_module
        return spec


def _route_torch_kernels() -> None:
    """Route torch's MKL kernels now if torch is loaded, else when it loads (once per process)."""
    if "torch" in sys.modules:
        from srmpc import pinned_kernels

        pinned_kernels.route()
    elif not any(isinstance(finder, _RouteWhenTorchLoads) for finder in sys.meta_path):
        sys.meta_path.insert(0, _RouteWhenTorchLoads())


def _restart(loaded: list[str]) -> None:
    """Start this process again with the same command line (the environment now pinned)."""
    arguments = list(getattr(sys, "orig_argv", []))[1:]
    if not arguments:
        raise NumericsError(f"{MODE_VARIABLE}={PINNED}: {', '.join(loaded)} was loaded before srmpc in an interactive "
                            f"session; set {MODE_VARIABLE} before starting Python and import srmpc first")
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, *arguments])


def library_versions() -> dict[str, str]:
    """Versions of :data:`FLOAT_LIBRARIES` that are installed, plus MKL's, oneDNN's and OpenBLAS's builds."""
    versions = {}
    for name in FLOAT_LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    if "torch" in sys.modules:
        for line in sys.modules["torch"].__config__.show().splitlines():
            if "Math Kernel Library Version" in line:
                versions["mkl"] = line.split("Version", 1)[1].split("for Intel")[0].strip()
            elif "MKL-DNN v" in line:
                versions["onednn"] = line.split("MKL-DNN", 1)[1].strip().split()[0]
    if "numpy" in sys.modules:
        blas = sys.modules["numpy"].show_config(mode="dicts").get("Build Dependencies", {}).get("blas", {})
        versions["numpy_blas"] = f"{blas.get('name', '?')} {blas.get('version', '?')}"
    return versions


def environment_record() -> dict:
    """What a run records about its numeric environment (``summary.json``'s :data:`SUMMARY_KEY`).

    ``numerics``: the mode; ``pinned``: the pinned variables as this process saw them (empty when native);
    ``replaced``: the machine's own values the pin replaced; ``kernels``: where torch's MKL ops ran (``numpy``
    when pinned and routed, ``mkl`` when torch is loaded natively, absent without torch); ``cpu``:
    :func:`cpu_summary`; ``threads``: torch's and numba's in this process; ``libraries``: :func:`library_versions`."""
    mode = requested_mode()
    threads = {}
    if "torch" in sys.modules:
        threads["torch"] = sys.modules["torch"].get_num_threads()
    if "numba" in sys.modules:
        threads["numba"] = sys.modules["numba"].get_num_threads()
    kernels = {}
    if "torch" in sys.modules:
        routed = "srmpc.pinned_kernels" in sys.modules and sys.modules["srmpc.pinned_kernels"].is_routed()
        kernels["kernels"] = "numpy" if routed else "mkl"
    return {
        "numerics": mode,
        "pinned": {name: os.environ.get(name) for name in PINNED_VARIABLES} if mode == PINNED else {},
        "replaced": json.loads(os.environ.get(REPLACED_VARIABLE, "{}")) if mode == PINNED else {},
        **kernels,
        "cpu": cpu_summary(),
        "threads": threads,
        "libraries": library_versions(),
    }


def mlflow_tags(record: dict) -> dict[str, str]:
    """The record's MLflow tags: ``numerics``, ``cpu_model`` and ``numerics.libraries`` (JSON)."""
    return {"numerics": record["numerics"], "cpu_model": record["cpu"]["model"],
            "numerics.libraries": json.dumps(record["libraries"], sort_keys=True)}

