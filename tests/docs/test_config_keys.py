"""Every configuration key the daemon accepts is documented, and every documented key exists:
the reference page (docs/reference/configuration.md) lists each ``section.key`` and
``sensor[i].key`` in its table, and the example configuration (deploy/tactiled.toml) shows each
key, set or commented out.  Compared both ways against what ``tactiled.settings`` reads."""

from __future__ import annotations

import re
from dataclasses import fields
from pathlib import Path

from tactiled import settings as settings_module
from tactiled.settings import SENSOR_FIELDS, Settings, settings_to_dict

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "docs" / "reference" / "configuration.md"
EXAMPLE = ROOT / "deploy" / "tactiled.toml"
ROW = re.compile(r"^\| `((?:[a-z0-9_]+|sensor\[i\])\.[a-z0-9_]+)` \|", re.MULTILINE)


def existing_keys() -> set[str]:
    """Every key the loader accepts: the settings' own tables, and the loader's key checks (so a
    key added to either side is seen)."""
    keys = set()
    for section, table in settings_to_dict(Settings()).items():
        if isinstance(table, dict):
            keys |= {f"{section}.{key}" for key in table}
        elif isinstance(table, list):
            keys |= {f"{section}[i].{key}" for key in table[0]}
    for section, checks in settings_module.SECTIONS.items():
        keys |= {f"{section}.{key}" for key in checks}
    keys |= {f"sensor[i].{key}" for key in SENSOR_FIELDS}
    return keys


def documented_keys() -> set[str]:
    return set(ROW.findall(REFERENCE.read_text()))


def test_every_existing_key_is_documented_and_every_documented_key_exists() -> None:
    existing, documented = existing_keys(), documented_keys()
    assert len(existing) >= 40, sorted(existing)
    assert existing - documented == set(), f"not in {REFERENCE.name}: {sorted(existing - documented)}"
    assert documented - existing == set(), f"documented but no such key: {sorted(documented - existing)}"


def test_the_example_configuration_shows_every_key() -> None:
    text = EXAMPLE.read_text()
    missing = [key for key in sorted(existing_keys())
               if not re.search(rf"^#? ?{re.escape(key.split('.')[-1])} =", text, re.MULTILINE)]
    assert missing == [], f"{EXAMPLE.name} does not show: {missing}"


def test_the_settings_sections_are_the_ones_the_loader_reads() -> None:
    """``Settings`` holds one table per section (and ``source``): a section added there and
    not to ``settings_to_dict`` (or the reverse) shows here."""
    names = {f.name for f in fields(Settings)} - {"source"}
    sections = {k.split(".")[0].split("[")[0] for k in existing_keys()}
    assert sections == {"sensor" if n == "sensors" else n for n in names}


def test_the_check_reads_the_table_it_compares() -> None:
    documented = documented_keys()
    assert {"server.port", "sensor[i].url", "fit.timeout", "zenoh.enabled"} <= documented
    assert ROW.findall("| `server.nonsense` | 1 | x |") == ["server.nonsense"]
