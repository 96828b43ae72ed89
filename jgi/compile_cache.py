"""A persistent compilation cache: XLA programs compiled once are read back by later processes.

Rendering a scene compiles each estimator's kernels for the scene's structure (its table sizes,
the materials and lights it uses, the estimator's static parameters); that takes seconds to
tens of seconds and is the same in every process. ``import jgi`` points JAX's persistent
compilation cache at a folder, so the second ``jgi render`` (or ``jgi.render`` in a new Python
process) of the same estimator on a scene of the same structure reads its programs from disk.
A program is looked up by a hash of the program itself, the compile options, the XLA flags
and the jax / jaxlib versions, so a stale entry is never used: it is simply not found.

* Folder: ``$JGI_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/jgi/xla`` (``~/.cache/jgi/xla``).
* Off: ``JGI_CACHE_DIR=off`` (or ``0``, ``none``, empty), or :func:`disable` in Python.
* A cache the user has already configured for JAX (``JAX_COMPILATION_CACHE_DIR``, or
  ``jax.config.update("jax_compilation_cache_dir", ...)`` before importing jgi) is left as it is.
* Programs that compile in under ``MIN_COMPILE_SECONDS`` are not stored (reading them back would
  cost about what compiling does); past ``MAX_BYTES`` (``JGI_CACHE_MAX_MB``) the least recently
  used entries are deleted (a scene structure's programs for every estimator take a few MB).

The cache changes no result: a program read back is the program that was compiled.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import jax

MIN_COMPILE_SECONDS = 0.2
MAX_BYTES = int(float(os.environ.get("JGI_CACHE_MAX_MB", "2048")) * 2**20)
_OFF = ("", "0", "off", "none", "false")


def default_folder() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jgi" / "xla"


def folder() -> Path | None:
    """The folder jgi's programs are cached in, or None when the cache is off."""
    current = jax.config.jax_compilation_cache_dir
    return Path(current) if current else None


def enable(path: str | os.PathLike | None = None) -> Path:
    """Cache compiled programs in ``path`` (default: :func:`default_folder`); returns it."""
    target = Path(path) if path is not None else default_folder()
    target.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(target))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    return target


def disable() -> None:
    """Compile every program anew (this process)."""
    jax.config.update("jax_compilation_cache_dir", None)


def configure_from_environment() -> Path | None:
    """What ``import jgi`` does: :func:`enable` at ``$JGI_CACHE_DIR`` or the default folder,
    unless it is off or JAX's cache was configured already. An unwritable folder leaves the
    cache off with a warning rather than failing the import."""
    if jax.config.jax_compilation_cache_dir:
        return folder()
    setting = os.environ.get("JGI_CACHE_DIR")
    if setting is not None and setting.strip().lower() in _OFF:
        return None
    try:
        return enable(setting or None)
    except OSError as e:
        warnings.warn(f"jgi: no compilation cache ({e}); set JGI_CACHE_DIR to a writable folder "
                      "or JGI_CACHE_DIR=off", stacklevel=2)
        return None
