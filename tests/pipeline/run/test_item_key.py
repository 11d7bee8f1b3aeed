"""ItemKey: typed item keys whose formatted strings are the manifest's keys."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline.run.keys import ItemKey
from pipeline.run.stage import Item

NAME = st.text(st.characters(blacklist_characters="/", blacklist_categories=("Cs",)),
               min_size=1, max_size=20).filter(lambda s: not s.startswith("_"))
KEYS = st.one_of(
    st.builds(ItemKey, NAME),
    st.builds(lambda r, k: ItemKey(r, shard=k), NAME, st.integers(0, 10**6)),
    st.builds(ItemKey, NAME, NAME, st.integers(0, 10**6)),
    st.builds(ItemKey.cross, NAME),
)


@given(KEYS)
def test_format_and_parse_are_inverse(key: ItemKey) -> None:
    assert ItemKey.parse(key.format()) == key
    assert str(key) == key.format()


@pytest.mark.parametrize(("text", "key"), [
    ("synth_corridor_s0", ItemKey("synth_corridor_s0")),
    ("rec/3", ItemKey("rec", shard=3)),
    ("rec/front/12", ItemKey("rec", "front", 12)),
    ("_latent_norm", ItemKey.cross("latent_norm")),
])
def test_the_manifest_spellings_are_unchanged(text: str, key: ItemKey) -> None:
    assert ItemKey.parse(text) == key
    assert key.format() == text
    assert Item(text, "ck").key == key  # a formatted key is parsed


@pytest.mark.parametrize("text", ["", "_", "a/b", "a/01", "a/-1", "a//1", "a/b/c/1", "a/b/²"])
def test_malformed_keys_are_refused_by_name(text: str) -> None:
    with pytest.raises(ValueError, match="item key"):
        ItemKey.parse(text)


def test_cross_items_have_no_recording() -> None:
    key = ItemKey.cross("clips")
    assert key.is_cross and key.recording is None
    with pytest.raises(ValueError, match="not an item of one recording"):
        key.require_recording()
    with pytest.raises(ValueError, match="starts with"):
        ItemKey("_rec")
