"""A private virtual X display (Xvfb) for running the viewer without a screen.

``virtual_display()`` starts Xvfb on a free display number (Xvfb picks it and reports it
through ``-displayfd``), yields ``":N"`` for the ``DISPLAY`` variable of the processes that
open windows, and stops the server afterwards.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from collections.abc import Iterator

from approxtree.errors import ContextUnavailableError


@contextlib.contextmanager
def virtual_display(screen: str = "1920x1080x24") -> Iterator[str]:
    """Run Xvfb with one screen of ``screen`` (WxHxDEPTH) for the block; yields ":N"."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        raise ContextUnavailableError(
            "Xvfb is not installed; install it (Debian/Ubuntu: apt-get install -y xvfb)."
        )
    read, write = os.pipe()
    proc = subprocess.Popen(
        [xvfb, "-displayfd", str(write), "-screen", "0", screen, "-nolisten", "tcp"],
        pass_fds=(write,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write)
    try:
        # Xvfb writes its display number once it accepts connections (EOF if it died).
        with os.fdopen(read) as f:
            number = f.readline().strip()
        if not number:
            raise ContextUnavailableError("Xvfb exited without opening a display.")
        yield f":{number}"
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
