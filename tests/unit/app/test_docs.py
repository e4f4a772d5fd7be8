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


def _worked_examples() -> str:
    return DOC[DOC.index("## 10. Worked examples"):]


def test_worked_examples_decode_with_the_real_codec():
    """Section 10 has one example per message, and each decodes with scenenav.core.contracts."""
    import json
    import re

    from scenenav.core.contracts import CameraFrame, decode, message_type
    section = _worked_examples()
    seen = set()
    for block in re.findall(r"```json\n(.*?)\n```", section, re.S):
        cls = message_type(json.loads(block)["type"])
        decode(cls, block.encode())
        seen.add(cls.__name__)
    (dump,) = re.findall(r"```text\n(.*?)\n```", section, re.S)
    data = bytes.fromhex("".join(line[10:57] for line in dump.splitlines()))
    header = json.loads(data[4:])
    assert int.from_bytes(data[:4], "little") == len(data) - 4
    pixels = bytes(header["width_px"] * header["height_px"] * 3)
    frame = decode(CameraFrame, data + pixels)
    assert frame.pixels.shape == (header["height_px"], header["width_px"], 3)
    seen.add("CameraFrame")
    assert seen == {cls.__name__ for cls in contracts.MESSAGE_TYPES}


def test_worked_examples_are_what_the_tool_prints():
    """tools/interface_examples.py writes section 10's examples; the page holds its current output."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("interface_examples",
                                                  REPO_ROOT / "tools" / "interface_examples.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert tool.markdown() in _worked_examples(), "run: python tools/interface_examples.py"


def test_documented_zenoh_config_is_valid_and_retries():
    """The JSON5 block of section 1 is a config zenoh accepts, with connect retries."""
    import json
    import re

    import zenoh
    block = re.search(r"```json5\n(.*?)\n```", DOC, re.S).group(1).replace("<hub_port>", "7447")
    conf = json.loads(zenoh.Config.from_json5(block).get_json("connect"))
    assert conf["timeout_ms"] == -1 and conf["retry"]["period_init_ms"] > 0
    assert conf["endpoints"] == ["tcp/127.0.0.1:7447"]
