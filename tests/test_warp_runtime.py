"""Warp's start-up: its notice that a machine has no NVIDIA driver is not passed on; anything
else it prints on stderr is."""

from __future__ import annotations

import os

import pytest

from physdrape.warp_runtime import NO_DRIVER_NOTICE, _stderr_without

NOTICE_LINE = f"Warp CUDA warning: {NO_DRIVER_NOTICE}. GPU execution will not be available.\n"


def test_the_notice_is_dropped_and_every_other_line_passed_on(capfd):
    with _stderr_without(NO_DRIVER_NOTICE):
        os.write(2, f"first line\n{NOTICE_LINE}last line\n".encode())  # as native code writes it
    err = capfd.readouterr().err
    assert err == "first line\nlast line\n"


def test_what_a_failing_block_printed_is_passed_on(capfd):
    with pytest.raises(RuntimeError, match="init failed"):
        with _stderr_without(NO_DRIVER_NOTICE):
            os.write(2, f"{NOTICE_LINE}Warp error: something real\n".encode())
            raise RuntimeError("init failed")
    assert capfd.readouterr().err == "Warp error: something real\n"
    os.write(2, b"after\n")  # descriptor 2 is the process's stderr again
    assert capfd.readouterr().err == "after\n"
