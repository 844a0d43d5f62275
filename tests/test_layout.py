"""The host and the kernel agree on what they share: a kernel hash that depends on the
sources' contents only, not on where they are installed."""
from __future__ import annotations

import re
import shutil

from warpe_cl.device import assemble_source, kernel_dir, source_hash
from warpe_cl.engine import WALK_FILES, walk_source_hash


def test_kernel_hash_does_not_depend_on_where_the_sources_are(tmp_path):
    """kernel_sha256 hashes the files' contents: two copies of cl/ in different folders have
    the same hash (their assembled text differs by its #line paths); a changed file or
    option changes it."""
    a, b = tmp_path / "one" / "cl", tmp_path / "elsewhere" / "deeper" / "cl"
    shutil.copytree(kernel_dir(), a)
    shutil.copytree(kernel_dir(), b)
    assert assemble_source(WALK_FILES, a) != assemble_source(WALK_FILES, b)
    assert source_hash(WALK_FILES, (), a) == source_hash(WALK_FILES, (), b) == walk_source_hash()
    assert source_hash(WALK_FILES, ("-DWARPE_DOUBLE",), a) != walk_source_hash()
    (b / "walk.cl").write_text((b / "walk.cl").read_text() + "\n")
    assert source_hash(WALK_FILES, (), b) != walk_source_hash()


def test_engine_records_the_kernel_hash(engine):
    from conftest import medium
    assert engine.kernel_hash in (None, walk_source_hash())
    engine.run(medium(), 100)
    assert engine.kernel_hash == walk_source_hash()
    assert re.fullmatch(r"[0-9a-f]{64}", engine.kernel_hash)
