"""Lazy, self-sufficient import of Open3D.

``import open3d`` needs the libusb-1.0 shared library, which minimal Linux images lack. The
``libusb-package`` wheel ships it; it is loaded globally before Open3D so that pip alone is
enough. Open3D takes about a second to import, so only code that needs it calls this.
"""

from __future__ import annotations

import ctypes
import functools
from typing import Any


class Open3DUnavailable(ImportError):
    """Open3D cannot be imported; the message names the fix."""


@functools.lru_cache(maxsize=1)
def import_open3d() -> Any:
    """Return the ``open3d`` module, loading libusb-1.0 from ``libusb-package`` first if present."""
    try:
        import libusb_package

        path = libusb_package.get_library_path()
        if path is not None:
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    except (ImportError, OSError):
        pass
    try:
        import open3d
    except ImportError as exc:  # pragma: no cover - depends on the machine
        if "libusb" in str(exc):
            raise Open3DUnavailable(
                "open3d needs libusb-1.0: run `pip install libusb-package` "
                "(or `apt-get install libusb-1.0-0`)") from exc
        raise Open3DUnavailable(f"open3d is not importable ({exc}): run `pip install open3d-cpu`") from exc
    return open3d
