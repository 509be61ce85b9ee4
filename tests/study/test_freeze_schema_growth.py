"""A frozen amendment stays frozen when the settings schema grows: a key added since (off by default) changes the
amendment's full recorded form, not the amendment. A real change, or a doctored record, is still a change."""

from __future__ import annotations

import copy
from typing import Any

from tactile_zoo.study.schema import Amendment, amendment_kept, canonical_hash

AMENDMENT = {"reason": "another CPU type", "rules": {"cpu": "AMD EPYC (AVX2)"},
             "grids": [{"name": "old", "settings": {"models": ["sgnet"], "datasets": "ev_objects", "seeds": [0, 5]}}]}


def _record(dump: dict[str, Any]) -> dict[str, Any]:
    return {"sha256": canonical_hash(dump), "amendment": dump, "time": "2026-12-07T07:49:00+0000"}


def _frozen_before_the_key_existed(key: str = "teachers") -> dict[str, Any]:
    """The record a freeze wrote when the bench settings had no ``key`` yet (its full form without it)."""
    dump = Amendment.model_validate(AMENDMENT).model_dump(mode="json")
    for grid in dump["grids"]:
        assert key in grid["settings"]  # the schema has it now, with its default
        del grid["settings"][key]
    return _record(dump)


def test_a_setting_added_to_the_schema_since_the_freeze_changes_no_frozen_amendment() -> None:
    record = _frozen_before_the_key_existed()
    now = Amendment.model_validate(AMENDMENT)
    assert canonical_hash(now.model_dump(mode="json")) != record["sha256"]  # the full form did move
    assert amendment_kept(record, now)
    assert amendment_kept(_record(now.model_dump(mode="json")), now)  # frozen under today's schema


def test_a_changed_amendment_or_a_doctored_record_is_not_kept() -> None:
    record = _frozen_before_the_key_existed()
    changed = copy.deepcopy(AMENDMENT)
    changed["grids"][0]["settings"]["seeds"] = [0, 6]
    assert not amendment_kept(record, Amendment.model_validate(changed))
    doctored = copy.deepcopy(record)
    doctored["amendment"]["grids"][0]["settings"]["seeds"] = [0, 6]  # the copy no longer matches its hash
    assert not amendment_kept(doctored, Amendment.model_validate(changed))
    unknown = copy.deepcopy(record["amendment"])
    unknown["grids"][0]["settings"]["retired_key"] = 1
    assert not amendment_kept(_record(unknown), Amendment.model_validate(AMENDMENT))
