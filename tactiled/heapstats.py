"""Where a process's memory is: figures for the soak, the worker-memory probe and the metrics."""

# * :func:`rss_mb`: resident set size of any process (``/proc/PID/statm``);
# * :func:`malloc_figures`: glibc malloc's own books (``mallinfo2``: bytes in use, free but kept,
#   mmapped; and from ``malloc_info`` the number of arenas and what each holds from the system);
# * :func:`pymalloc_figures`: Python's small-object allocator (1 MiB arenas held, bytes of live
#   objects in them);
# * :func:`heap_figures`: all of them, one flat dict of numbers (MB, counts);
# * :func:`fitter_cache_figures` (the fitter's quadrature-rule caches and start tables),
#   :func:`gc_figures` (the cyclic collector), and :func:`worker_figures`, what a fit worker
#   answers to the pool's ``memory`` request.
#
# RSS that grows while the bytes in use do not is an allocator keeping freed memory
# (fragmentation), not a leak; bytes in use that grow are a leak or a cache filling up.  Linux
# and glibc only; elsewhere the functions return ``None`` or ``{}``.

from __future__ import annotations

import ctypes
import math
import os
import re
import sys
import tempfile
from typing import Any

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_MB = 1.0 / 2**20


def rss_mb(pid: int | str = "self") -> float | None:
    """Resident set size of process ``pid`` in MiB (``/proc/PID/statm``), None if it is gone
    (or there is no /proc)."""
    try:
        with open(f"/proc/{pid}/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * _PAGE * _MB
    except (OSError, IndexError, ValueError):
        return None


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]


_LIBC: list[Any] = []


def _libc() -> Any:
    """This process's C library, loaded once: every ``ctypes.CDLL`` makes a class of its own
    (its function pointer type), which dies only in a cyclic collection, so one per call would
    be the very creep these figures look for."""
    if not _LIBC:
        try:
            _LIBC.append(ctypes.CDLL(None))
        except OSError:
            _LIBC.append(None)
    return _LIBC[0]


_ARENA_RE = re.compile(r'<heap nr="(\d+)">.*?<system type="current" size="(\d+)"/>', re.S)


def malloc_figures() -> dict[str, float]:
    """glibc malloc: ``malloc_in_use_mb`` (bytes handed out and not freed),
    ``malloc_free_kept_mb`` (freed, still held from the system), ``malloc_mmapped_mb``
    (large blocks mapped on their own), ``malloc_arenas`` (arenas: one per thread that
    allocated, up to 8 per core) and ``malloc_arena_system_mb`` (what they hold from the
    system in all).  {} without glibc 2.33+."""
    libc = _libc()
    if libc is None or not hasattr(libc, "mallinfo2"):
        return {}
    libc.mallinfo2.restype = _MallInfo2
    m = libc.mallinfo2()
    out: dict[str, float] = {
        "malloc_in_use_mb": round(m.uordblks * _MB, 3),
        "malloc_free_kept_mb": round(m.fordblks * _MB, 3),
        "malloc_mmapped_mb": round(m.hblkhd * _MB, 3),
        "malloc_mmapped_blocks": int(m.hblks),
    }
    text = malloc_info_xml()
    if text:
        arenas = _ARENA_RE.findall(text)
        out["malloc_arenas"] = len(arenas)
        out["malloc_arena_system_mb"] = round(sum(int(s) for _, s in arenas) * _MB, 3)
    return out


def malloc_info_xml() -> str:
    """glibc's ``malloc_info(0, fp)`` report (XML), or "" where it is not available."""
    libc = _libc()
    if libc is None or not hasattr(libc, "malloc_info"):
        return ""
    libc.fopen.restype = ctypes.c_void_p
    libc.fopen.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
    libc.fclose.argtypes = [ctypes.c_void_p]
    libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
    with tempfile.NamedTemporaryFile(prefix="tactiled-malloc-", suffix=".xml") as tmp:
        fp = libc.fopen(tmp.name.encode(), b"w")
        if not fp:
            return ""
        try:
            libc.malloc_info(0, fp)
        finally:
            libc.fclose(fp)
        return open(tmp.name, encoding="ascii", errors="replace").read()


def pymalloc_figures() -> dict[str, float]:
    """pymalloc's ``pymalloc_arenas`` (1 MiB arenas held) and ``pymalloc_live_mb`` (bytes of
    live objects in them), from ``sys._debugmallocstats()`` (which writes to the C-level
    stderr: pointed at a file for the call).  {} if unavailable."""
    stats = getattr(sys, "_debugmallocstats", None)
    if stats is None:
        return {}
    with tempfile.TemporaryFile() as f:
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError):
            pass
        saved = os.dup(2)
        os.dup2(f.fileno(), 2)
        try:
            stats()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        f.seek(0)
        text = f.read().decode(errors="replace")
    found = dict(re.findall(r"^# (arenas allocated current|bytes in allocated blocks)\s+=\s+"
                            r"([\d,]+)", text, re.MULTILINE))
    if len(found) < 2:
        return {}
    return {"pymalloc_arenas": int(found["arenas allocated current"].replace(",", "")),
            "pymalloc_live_mb": round(int(found["bytes in allocated blocks"].replace(",", ""))
                                      * _MB, 3)}


def rss_parts_mb(pid: int | str = "self") -> dict[str, float]:
    """The resident set split as the kernel books it (``/proc/PID/status``): ``rss_anon_mb``
    (heap, stacks, anonymous mappings: what allocators hold) and ``rss_file_mb`` (pages of
    mapped files touched: code of the libraries and of the compiled core).  {} if
    unavailable."""
    keys = {"RssAnon:": "rss_anon_mb", "RssFile:": "rss_file_mb"}
    out: dict[str, float] = {}
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                name = line.split(None, 1)[0] if line.strip() else ""
                if name in keys:
                    out[keys[name]] = round(int(line.split()[1]) / 1024.0, 3)
    except (OSError, ValueError, IndexError):
        return {}
    return out


def heap_figures() -> dict[str, float]:
    """RSS (and its parts) and every figure above, for this process (one flat dict)."""
    out: dict[str, float] = {}
    rss = rss_mb()
    if rss is not None:
        out["rss_mb"] = round(rss, 3)
    out.update(rss_parts_mb())
    out.update(malloc_figures())
    out.update(pymalloc_figures())
    return out


def _lru_keys(fn: Any) -> list[Any]:
    """The keys held by an ``functools.lru_cache`` (its cache dict, found among the wrapper's
    references), [] if it cannot be seen."""
    import gc

    for ref in gc.get_referents(fn):
        if isinstance(ref, dict) and ref and all(isinstance(k, (int, tuple)) for k in ref):
            return list(ref)
    return []


def rule_cache_bytes(rules: Any) -> int:
    """Bytes of the quadrature rules cached by :mod:`tactiled.physics.quadrature_rules`, from the cache
    keys (node counts): a 1-D rule of n nodes holds 2 arrays of n doubles, a disk rule of
    ``(n_u, n_s)`` nodes 3 arrays of ``n_u n_s``."""
    total = 0
    for name, arrays in (("_rule_u", 2), ("_rule_s", 2), ("_kept_disk_rule", 3),
                         ("disk_rule", 3)):
        fn = getattr(rules, name, None)
        for key in _lru_keys(fn) if fn is not None else ():
            nodes = key if isinstance(key, int) else math.prod(k for k in key if isinstance(k, int))
            total += arrays * 8 * nodes
    return total


def fitter_cache_figures() -> dict[str, int]:
    """Entries of the fitter's per-process caches: the quadrature rules of
    :mod:`tactiled.physics.quadrature_rules` (1-D Gauss rules by node count, 2-D disk rules by pair of
    counts) and the start tables.  Only modules already imported are looked at."""
    out: dict[str, int] = {}
    rules = sys.modules.get("tactiled.physics.quadrature_rules")
    if rules is not None:
        for name, key in (("_rule_u", "rule_u"), ("_rule_s", "rule_s"),
                          ("_kept_disk_rule", "disk_rule"), ("disk_rule", "disk_rule")):
            fn = getattr(rules, name, None)
            if fn is not None and hasattr(fn, "cache_info"):
                out[f"cache_{key}"] = fn.cache_info().currsize
        out["cache_rule_mb"] = round(rule_cache_bytes(rules) * _MB, 3)
    start = sys.modules.get("tactiled.fit.start")
    if start is not None and hasattr(start, "start_table"):
        out["cache_start_table"] = start.start_table.cache_info().currsize
    return out


def gc_figures() -> dict[str, int]:
    """The cyclic collector's state: objects it tracks (``gc_objects``), full collections so
    far and the objects they freed (``gc_full_collections``, ``gc_full_collected``): garbage
    that waits for a rare full collection shows as live bytes in between."""
    import gc

    full = gc.get_stats()[2]
    return {"gc_objects": len(gc.get_objects()), "gc_full_collections": full["collections"],
            "gc_full_collected": full["collected"]}


def worker_figures() -> dict[str, float]:
    """What a fit worker reports about its memory: :func:`heap_figures`,
    :func:`fitter_cache_figures` and :func:`gc_figures`."""
    return {**heap_figures(), **fitter_cache_figures(), **gc_figures()}
