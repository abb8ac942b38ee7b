"""Test-session settings: the mesh cache (:mod:`cellsight.geometry.mesh_cache`) lives in a
temporary folder of the session's own, never in the user's cache, and is removed at the end;
subprocesses started by the tests inherit it."""

from __future__ import annotations

import os
import shutil
import tempfile

CACHE = tempfile.mkdtemp(prefix="cellsight-test-cache-")
os.environ["CELLSIGHT_CACHE_DIR"] = CACHE


def pytest_sessionfinish(session, exitstatus) -> None:  # noqa: ARG001 (pytest's hook)
    shutil.rmtree(CACHE, ignore_errors=True)
