"""Anyone's method beside gridflow's: the interface the benchmark runs methods through.

A **method** is a Python callable with the positional signature of
:func:`gridflow.estimator.estimate`::

    fn(volume, focal_length, camera_spacing, *, principal_point=None) -> Mapping[str, ndarray]

``volume`` has shape ``(T, Sy, Sx, H, W)`` (read-only); the method returns the ``(H, W)``
maps of the centre camera at the middle frame ``(T - 1) // 2`` under
gridflow's quantity names (:data:`QUANTITIES`: ``Z, Zx, Zy, disparity, Ux, Uy, Uz, growth,
rotation, a1, ...``), NaN where it has no value, any subset of them: it is scored on what
it returns.  On the command line a method is

- ``MODULE:FUNCTION``, importable from the current folder or ``PYTHONPATH``;
- the name of an entry point that an installed package registers in the group
  ``gridflow.methods`` (:data:`ENTRY_POINT_GROUP`);
- a program in any language (``--method-cmd 'PROGRAM ARGS {input} {output}'``): gridflow
  writes the volume as an interchange ``.npz`` at ``{input}`` (a volume file without
  truth: ``volume``, ``focal_length``, ``camera_spacing``, ``principal_point``) and reads
  the maps the program writes as an ``.npz`` at ``{output}``.

:func:`load_method` and :func:`command_method` resolve them into a :class:`Method`;
:func:`run_method` calls one on a volume and checks what comes back, so that a method that
fails is a one-line :class:`MethodError` naming it and what was wrong.  A method's
``version`` (a hash of its code: the module's source file, or the command and its
program's file) keys the sweep's finished points, so that a resumed sweep never mixes two
versions of one method.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gridflow.errors import GridflowError, UsageError

__all__ = ["Method", "MethodError", "load_method", "command_method", "resolve_methods",
           "run_method", "QUANTITIES", "BUILTIN", "ENTRY_POINT_GROUP", "DEFAULT_TIMEOUT"]

# the built-in estimator's name in a sweep's method column
BUILTIN = "gridflow"
ENTRY_POINT_GROUP = "gridflow.methods"
# seconds a --method-cmd program may take per volume before it is stopped
DEFAULT_TIMEOUT = 600.0


def _quantities() -> tuple[str, ...]:
    """Every map name a gridflow model writes (all brightness and motion models)."""
    from gridflow.estimator import MODELS, MOTIONS
    from gridflow.estimator.models import get_model

    names: list[str] = []
    for m in MODELS:
        for motion in MOTIONS:
            for dims in (1, 2):
                for q in get_model(m, dims, False, motion).outputs:
                    if q not in names:
                        names.append(q)
    # and what every estimate adds: the smallest eigenvalue of J
    return tuple(names) + ("model_error",)


QUANTITIES = _quantities()


class MethodError(GridflowError):
    """A method that cannot be loaded, fails, or returns what is not maps."""


@dataclass(frozen=True)
class Method:
    """A method, resolved.

    Attributes
    ----------
    name : str
        What the sweep's ``method`` column says: ``MODULE:FUNCTION``, the entry point's
        name, or the command as given.
    kind : {"python", "command"}
    version : str
        A hash of the method's code (12 hex digits).
    fn : callable
        ``fn(volume, focal_length, camera_spacing, *, principal_point=None)``.
    timeout : float or None
        Seconds per volume (commands only).
    """

    name: str
    kind: str
    version: str
    fn: Callable = field(compare=False, repr=False)
    timeout: float | None = None


def _file_hash(h, path) -> None:
    try:
        h.update(Path(path).read_bytes())
    except OSError:
        h.update(f"unreadable:{path}".encode())


def _source_file(fn):
    """The source file of ``fn`` (a function, a ``functools.partial`` of one, or a callable
    instance: its class's), or None."""
    import functools

    while isinstance(fn, functools.partial):
        fn = fn.func
    for obj in (inspect.unwrap(fn), type(fn)):
        try:
            return inspect.getsourcefile(obj)
        except TypeError:
            continue
    return None


def _python_version(fn, extra: str = "") -> str:
    """A hash of the source file of ``fn``'s module (and ``extra``); of its qualified name
    where it has no source file (a built-in), never of an address."""
    h = hashlib.sha1(extra.encode())
    src = _source_file(fn)
    if src:
        _file_hash(h, src)
    else:
        h.update(f"{getattr(fn, '__module__', '')}.{getattr(fn, '__qualname__', '')}"
                 .encode())
    return h.hexdigest()[:12]


# the hash of each method module's file as it was imported: a module whose file changed
# since is imported again, so that the code that runs is the code the version names
_IMPORTED: dict[str, str] = {}


def _import_current(name: str):
    mod = importlib.import_module(name)
    path = getattr(mod, "__file__", None)
    if path and Path(path).is_file():
        digest = hashlib.sha1(Path(path).read_bytes()).hexdigest()
        if _IMPORTED.setdefault(name, digest) != digest:
            mod = importlib.reload(mod)
            _IMPORTED[name] = digest
    return mod


def load_method(spec: str) -> Method:
    """The Python method ``spec``: ``MODULE:FUNCTION`` (imported from the current folder or
    ``PYTHONPATH``) or the name of an entry point in the group ``gridflow.methods``.

    Raises
    ------
    MethodError
        The module does not import, has no such function, the name is no entry point, or
        what it names is not callable.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise MethodError(f"--method: give MODULE:FUNCTION or an entry point's name, got "
                          f"{spec!r}")
    if ":" in spec:
        mod_name, _, fn_name = spec.partition(":")
        if "" not in sys.path and "." not in sys.path:
            # the current folder, as `python -m` has it
            sys.path.insert(0, "")
        try:
            mod = _import_current(mod_name)
        except (Exception, SystemExit) as exc:   # noqa: BLE001 - the method's failure
            raise MethodError(f"--method {spec}: module {mod_name!r} does not import "
                              f"({type(exc).__name__}: {exc})") from None
        fn = mod
        for part in fn_name.split("."):
            fn = getattr(fn, part, None)
            if fn is None:
                raise MethodError(f"--method {spec}: module {mod_name!r} has no "
                                  f"{fn_name!r}")
        extra = ""
    else:
        from importlib.metadata import entry_points

        found = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == spec]
        if not found:
            known = sorted(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))
            raise MethodError(f"--method {spec}: not MODULE:FUNCTION, and no installed "
                              f"package registers it in the entry point group "
                              f"{ENTRY_POINT_GROUP!r} (registered: "
                              f"{', '.join(known) or 'none'})")
        ep = found[0]
        try:
            fn = ep.load()
        except (Exception, SystemExit) as exc:   # noqa: BLE001
            raise MethodError(f"--method {spec}: entry point {ep.value!r} does not load "
                              f"({type(exc).__name__}: {exc})") from None
        dist = getattr(ep, "dist", None)
        extra = f"{ep.value}@{getattr(dist, 'version', '')}"
    if not callable(fn):
        raise MethodError(f"--method {spec}: {fn!r} is not callable")
    return Method(spec, "python", _python_version(fn, extra), fn)


def command_method(cmd: str, timeout: float = DEFAULT_TIMEOUT) -> Method:
    """The program ``cmd`` (``'PROGRAM ARGS {input} {output}'``, split like a shell line)
    as a method: each volume is written as an interchange ``.npz`` at ``{input}``, the
    program runs (at most ``timeout`` s) and its ``.npz`` of maps at ``{output}`` is read.
    """
    try:
        args = shlex.split(cmd)
    except (ValueError, AttributeError) as exc:
        raise MethodError(f"--method-cmd {cmd!r}: not a command line ({exc})") from None
    text = " ".join(args)
    if not args or "{input}" not in text or "{output}" not in text:
        raise MethodError(f"--method-cmd {cmd!r}: the command must contain {{input}} and "
                          "{output} (where gridflow writes the volume and the program its "
                          "maps)")
    if not (0 < timeout < float("inf")):
        raise MethodError(f"--method-timeout must be a finite number of seconds > 0, got "
                          f"{timeout}")
    program = shutil.which(args[0]) or args[0]
    h = hashlib.sha1(cmd.encode())
    # the program's own file and, for an interpreter, the script it runs
    for a in [program] + args[1:]:
        if "{" not in a and Path(a).is_file():
            _file_hash(h, a)
    return Method(cmd, "command", h.hexdigest()[:12],
                  lambda *a, **k: _run_command(cmd, args, timeout, *a, **k), timeout)


def resolve_methods(methods=(), commands=(), timeout: float = DEFAULT_TIMEOUT) -> list:
    """``methods`` (``"gridflow"`` for the built-in estimator, kept as that string, or
    :func:`load_method` specs) and ``commands`` (:func:`command_method`), resolved."""
    out = [m if m == BUILTIN else load_method(m) for m in methods]
    out += [command_method(c, timeout) for c in commands]
    names = [m if isinstance(m, str) else m.name for m in out]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise UsageError(f"methods given twice: {', '.join(twice)}")
    return out


def _run_command(cmd, args, timeout, volume, focal_length, camera_spacing, *,
                 principal_point=None):
    from gridflow.io import load_npz_maps, save_volume
    from gridflow.volume import GridVolume

    H, W = volume.shape[-2:]
    pp = principal_point if principal_point is not None else ((W - 1) / 2, (H - 1) / 2)
    # the paths go into the command line, perhaps into a shell's string (sh -c '... {input}'):
    # a folder whose name a shell would split or expand is avoided where /tmp is there
    base = tempfile.gettempdir()
    if shlex.quote(base) != base and Path("/tmp").is_dir():
        base = "/tmp"
    with tempfile.TemporaryDirectory(prefix="gridflow-method-", dir=base) as tmp:
        inp, out = Path(tmp) / "input.npz", Path(tmp) / "output.npz"
        save_volume(inp, GridVolume(np.asarray(volume), float(focal_length),
                                    tuple(float(s) for s in camera_spacing),
                                    (float(pp[0]), float(pp[1])), {}, {}))
        run = [a.replace("{input}", str(inp)).replace("{output}", str(out)) for a in args]
        try:
            # a session of its own: on timeout the program and everything it started go
            proc = subprocess.Popen(run, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    stdin=subprocess.DEVNULL, start_new_session=True)
        except FileNotFoundError:
            raise MethodError(f"method {cmd!r}: no program {args[0]!r}") from None
        except PermissionError:
            raise MethodError(f"method {cmd!r}: {args[0]!r} is not executable") from None
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except BaseException as exc:
            _kill_group(proc)
            if isinstance(exc, subprocess.TimeoutExpired):
                raise MethodError(f"method {cmd!r}: did not finish within {timeout:g} s "
                                  "(--method-timeout)") from None
            raise
        if proc.returncode != 0:
            text = (stderr or stdout or b"").decode("utf-8", errors="replace").strip()
            last = text.splitlines()[-1:] or ["no output"]
            raise MethodError(f"method {cmd!r}: exited with status {proc.returncode} "
                              f"({last[0][:200]})")
        if not out.is_file():
            raise MethodError(f"method {cmd!r}: wrote nothing at {{output}}")
        try:
            # a gridflow estimate file (gridflow estimate {input} -o {output} as the
            # program) holds its interior too: not a map
            return {k: v for k, v in load_npz_maps(out).items() if k != "interior"}
        except GridflowError as exc:
            raise MethodError(f"method {cmd!r}: its output {exc}") from None


def _kill_group(proc) -> None:
    """Stop a program started in a session of its own, with what it started."""
    import os
    import signal

    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.communicate()


def run_method(method: Method, volume: np.ndarray, focal_length: float, camera_spacing,
               principal_point=None) -> tuple[dict[str, np.ndarray], float]:
    """Call ``method`` on a volume of shape ``(T, Sy, Sx, H, W)`` and check its maps.

    Returns
    -------
    maps : dict of str to ndarray, each float64 shape (H, W)
    seconds : float
        The call's wall time.

    Raises
    ------
    MethodError
        The method raised, returned no mapping, names no gridflow quantity, or returned
        arrays of another shape or not of numbers.
    """
    H, W = volume.shape[-2:]
    # a read-only view: a method that wrote into its input would change what the next
    # method (and the next point, made from the same rendering) sees
    view = np.asarray(volume).view()
    view.flags.writeable = False
    t0 = time.perf_counter()
    try:
        out = method.fn(view, focal_length, camera_spacing, principal_point=principal_point)
    except MethodError:
        raise
    except (Exception, SystemExit) as exc:   # noqa: BLE001 - the method's failure, named
        raise MethodError(f"method {method.name}: raised {type(exc).__name__}: "
                          f"{str(exc)[:300]}") from None
    seconds = time.perf_counter() - t0
    if not isinstance(out, Mapping):
        raise MethodError(f"method {method.name}: returned {type(out).__name__}, expected "
                          "a mapping of quantity names to (H, W) arrays")
    unknown = [k for k in out if k not in QUANTITIES]
    if unknown:
        raise MethodError(f"method {method.name}: returned maps under names gridflow does "
                          f"not score: {', '.join(map(str, unknown))} (known: "
                          f"{', '.join(QUANTITIES)})")
    if not out:
        raise MethodError(f"method {method.name}: returned no maps")
    maps = {}
    for k, v in out.items():
        kind = np.asarray(v).dtype.kind
        if kind not in "iuf":
            raise MethodError(f"method {method.name}: map {k!r} is not an array of real "
                              f"numbers (dtype {np.asarray(v).dtype})")
        a = np.asarray(v, dtype=np.float64)
        if a.shape != (H, W):
            raise MethodError(f"method {method.name}: map {k!r} has shape {a.shape}, "
                              f"expected the images' {(H, W)}")
        maps[k] = a
    return maps, seconds


def estimate_with_method(source_path, output, method: Method) -> list[str]:
    """``gridflow estimate INPUT --method ... -o OUTPUT.npz``: run ``method`` on the whole
    input (a volume ``.npz``, a camera-grid folder, an HCI scene: anything
    :func:`gridflow.sources.open_source` reads, in memory) and write its maps as an
    estimate ``.npz`` that ``gridflow evaluate`` scores.  Its ``interior`` is the built-in
    estimator's at the default settings (the pixels with a whole window), so that every
    method is scored over the same pixels.  Returns the report's lines."""
    from gridflow.estimator import Estimate, window_halo
    from gridflow.estimator.settings import EstimatorSettings
    from gridflow.io import check_output, save_estimate
    from gridflow.sources import open_source

    out = check_output(output, suffixes=".npz", inputs=[source_path], what="-o")
    src = open_source(source_path)
    # a method estimates the middle frame (the interface's convention): an input whose
    # truth or reference is another frame would be scored against the wrong one
    mid = (src.frames - 1) // 2
    for what, k in (("truth", src.truth_frame), ("reference", src.ref_frame)):
        if k is not None and k != mid:
            raise UsageError(f"{source_path}: its {what} frame is {k}; a method estimates "
                             f"the middle frame {mid} of the {src.frames}")
    vol = src.load()
    maps, seconds = run_method(method, vol.volume, vol.focal_length, vol.camera_spacing,
                               principal_point=vol.principal_point)
    H, W = vol.volume.shape[-2:]
    halo = window_halo(EstimatorSettings())
    interior = np.zeros((H, W), bool)
    interior[halo:H - halo, halo:W - halo] = True
    settings = {"method": method.name, "method_version": method.version,
                "seconds": round(seconds, 3), "ref_frame": mid}
    save_estimate(out, Estimate(maps, method.name, interior, settings))
    return [f"method {method.name}: {len(maps)} map(s) ({', '.join(maps)}) in "
            f"{seconds:.2f} s; wrote {out} (score it: gridflow evaluate {out} INPUT)"]
