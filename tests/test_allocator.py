"""The command line's allocator settings (gridflow.bench.cli._allocator): what glibc does
with them, read back from glibc itself in a fresh process, beside a process without them.
"""

import os
import subprocess
import sys
import textwrap

import pytest

from gridflow.bench.cli import _allocator



def _glibc() -> bool:
    try:
        return (sys.platform.startswith("linux")
                and (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc"))
    except (ValueError, OSError):
        return False


GLIBC = _glibc()

# A fresh process: tune (or not); hold 16 arrays of 20 MiB and one of 200 MiB, free them, then four threads that each
# allocate and free arrays.  It prints glibc's own account: the settings made, the heaps
# (arenas) in use (malloc_info), the bytes the arrays took in mapped chunks, and the
# free bytes the heap kept after they were freed (mallinfo2).
_PROBE = textwrap.dedent("""
    import ctypes, sys, tempfile, threading
    from gridflow.bench.cli._allocator import tune_allocator
    made = tune_allocator() if sys.argv[1] == "tune" else ()
    import numpy as np
    libc = ctypes.CDLL(None)
    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
            "uordblks", "fordblks", "keepcost")]
    libc.mallinfo2.restype = MallInfo2
    m0 = libc.mallinfo2()
    held = [np.empty(20 * 2**20 // 8) for _ in range(16)] + [np.empty(200 * 2**20 // 8)]
    m1 = libc.mallinfo2()
    del held
    m2 = libc.mallinfo2()
    def work():
        for _ in range(3):
            b = np.ones(2**20)
            del b
    threads = [threading.Thread(target=work) for _ in range(4)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    with tempfile.NamedTemporaryFile(suffix=".xml") as f:
        libc.fopen.restype = ctypes.c_void_p
        libc.fopen.argtypes = (ctypes.c_char_p, ctypes.c_char_p)
        libc.malloc_info.argtypes = (ctypes.c_int, ctypes.c_void_p)
        libc.fclose.argtypes = (ctypes.c_void_p,)
        fp = libc.fopen(f.name.encode(), b"w")
        libc.malloc_info(0, fp)
        libc.fclose(fp)
        heaps = open(f.name).read().count("<heap nr=")
    print(len(made), heaps, m1.hblkhd - m0.hblkhd, m2.fordblks)
""")


def _probe(mode: str, **env):
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True,
                         text=True, check=True,
                         env={**{k: v for k, v in os.environ.items()
                                 if not k.startswith("MALLOC_")
                                 and k not in ("GLIBC_TUNABLES", "GRIDFLOW_MALLOC")},
                              **env})
    made, heaps, mapped, free = (int(v) for v in out.stdout.split())
    return made, heaps, mapped, free


@pytest.mark.skipif(not GLIBC, reason="the settings are glibc's; elsewhere nothing is set "
                                      "(test_nothing_is_set_where_the_user_says_so)")
def test_the_settings_give_one_arena_heap_arrays_and_kept_free_memory():
    """Tuned: the threads share one arena; 16 arrays of 20 MiB and one of 200 MiB come
    from the heap (no mapped chunk); once freed, the heap keeps all of
    it for the next step.  Untuned, the same process has more than one arena, maps every
    one of the arrays and keeps none of them (the control: the probe sees the
    difference)."""
    made, heaps, mapped, free = _probe("tune")
    assert made == len(_allocator.SETTINGS)
    assert heaps == 1
    assert mapped == 0
    assert free >= 520 * 2**20
    made, heaps, mapped, free = _probe("none")
    assert made == 0
    assert heaps > 1
    assert mapped >= 520 * 2**20
    assert free < 20 * 2**20


@pytest.mark.skipif(not GLIBC, reason="the settings are glibc's")
def test_the_users_own_settings_and_the_opt_out_are_left_alone():
    """MALLOC_ARENA_MAX given by the user: gridflow sets nothing (glibc takes theirs: 2
    arenas at most here); GRIDFLOW_MALLOC=system: nothing set, glibc's defaults."""
    made, heaps, _, _ = _probe("tune", MALLOC_ARENA_MAX="2")
    assert made == 0 and heaps == 2
    made, heaps, mapped, _ = _probe("tune", GRIDFLOW_MALLOC="system")
    assert made == 0 and heaps > 1 and mapped >= 520 * 2**20


def test_nothing_is_set_where_the_user_says_so():
    """The opt-outs return before any call into the C library (so on every platform):
    any MALLOC_* variable, glibc's malloc tunables, GRIDFLOW_MALLOC=system; tunables of
    other parts of glibc are not the user's malloc settings."""
    for env in ({"GRIDFLOW_MALLOC": "system"}, {"GRIDFLOW_MALLOC": " System "},
                {"MALLOC_ARENA_MAX": "4"}, {"MALLOC_PERTURB_": "0"},
                {"GLIBC_TUNABLES": "glibc.malloc.arena_max=4"},
                {"MALLOC_TRIM_THRESHOLD_": "0"}):
        assert _allocator.tune_allocator(env) == ()
    assert not _allocator._users_own({"GLIBC_TUNABLES": "glibc.pthread.rseq=0"})
    assert _allocator._users_own({"GLIBC_TUNABLES": "glibc.pthread.rseq=0:"
                                                    "glibc.malloc.mmap_max=1"})


@pytest.mark.skipif(not GLIBC, reason="the settings are glibc's")
def test_the_console_script_tunes_before_numpy_and_threads(tmp_path):
    """gridflow's own process tunes first thing: numpy not yet imported, no thread but
    the main one (an arena already given to a thread would stay its own)."""
    code = textwrap.dedent("""
        import sys, threading
        from gridflow.bench.cli import _allocator
        real = _allocator.tune_allocator
        def spy():
            print("STATE", "numpy" in sys.modules, threading.active_count(), len(real()))
            return ()
        _allocator.tune_allocator = spy
        # parsed, then refused (no such input): past the parser, which imports numpy
        sys.argv = ["gridflow", "estimate", "no-such-input.npz", "-o", "no-such-output.npz"]
        from gridflow.bench.cli import main
        print("STATUS", main())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=tmp_path,
                         env={k: v for k, v in os.environ.items()
                              if not k.startswith("MALLOC_")
                              and k not in ("GLIBC_TUNABLES", "GRIDFLOW_MALLOC")})
    state = [line.split()[1:] for line in out.stdout.splitlines()
             if line.startswith(("STATE", "STATUS"))]
    assert state == [["False", "1", str(len(_allocator.SETTINGS))], ["2"]], out.stdout


def test_only_the_command_lines_own_process_is_tuned(monkeypatch):
    """main() from the console script (no arguments) tunes; main([...]) called from
    someone's process (a test, a script) does not."""
    from gridflow.bench import cli

    calls = []
    monkeypatch.setattr(_allocator, "tune_allocator", lambda: calls.append(1) or ())
    monkeypatch.setattr(sys, "argv", ["gridflow", "estimate", "--help"])
    with pytest.raises(SystemExit):
        cli.main()
    assert calls == [1]
    with pytest.raises(SystemExit):
        cli.main(["estimate", "--help"])
    assert calls == [1]
