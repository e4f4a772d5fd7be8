"""docs/interfaces.md must name every message, field and key of the contracts."""

import dataclasses

from support import REPO_ROOT

from scenenav.core import contracts
from scenenav.core.keys import Keys, key_types

DOC = (REPO_ROOT / "docs" / "interfaces.md").read_text()


def test_every_message_and_field_documented():
    for cls in contracts.MESSAGE_TYPES:
        assert f"### {cls.__name__} (version {cls.VERSION})" in DOC, cls.__name__
        for f in dataclasses.fields(cls):
            if f.name != "pixels":
                assert f"`{f.name}`" in DOC, f"{cls.__name__}.{f.name}"


def test_every_key_documented():
    k = Keys("ns")
    for key in key_types(k):
        tail = key[len(k.root) + 1:].replace("*", "<id>")
        assert f"`{tail}`" in DOC, tail


def test_scenario_schema_page_is_current():
    from scenenav.app.schema_doc import render
    page = (REPO_ROOT / "docs" / "scenarios-schema.md").read_text()
    assert page == render(), "run: python -m scenenav.app.schema_doc > docs/scenarios-schema.md"


def test_architecture_module_map_is_current():
    """docs/architecture.md's module map is what tools/module_map.py prints for this checkout."""
    import subprocess
    import sys
    r = subprocess.run([sys.executable, str(REPO_ROOT / "tools" / "module_map.py"), "--check",
                        str(REPO_ROOT / "docs" / "architecture.md")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
