"""``read_bag_raw``'s own MCAP reading (``bag._fast_batches``: chunks merged a list at a time) hands out the
same messages in the same order as rosbags' own loop (``heapq.merge`` of the chunks), also where chunks
overlap in time and log times repeat, and ``read_bag_raw_batches`` is ``read_bag_raw`` in lists."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader
from std_msgs.msg import String

from terrain_estimation import bag
from terrain_estimation.bag import AtomicBagWriter, read_bag_raw, read_bag_raw_batches

BAGS = Path(__file__).resolve().parents[1] / "bags"


def _items(path: Path, fast: bool, monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, int, bytes]]:
    monkeypatch.setattr(bag, "_FAST_READ", fast)
    return [(conn.topic, t, raw) for conn, t, raw, _decode in read_bag_raw(path)]


@pytest.fixture(scope="module")
def overlapping(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Messages of ~200 kB (rosbags closes a chunk past 1 MiB: about 5 a chunk), their log times going back
    and forth across the chunks and repeating, on two topics."""
    rng = random.Random(7)
    out = tmp_path_factory.mktemp("batches") / "overlapping"
    with AtomicBagWriter(out) as writer:
        for i in range(60):
            t = 1_000_000_000 + 10_000_000 * (i + rng.choice((-7, -3, -1, 0, 0, 0, 2, 5)))
            msg = String(data=f"{i:03d}" + "x" * rng.randint(150_000, 250_000))
            writer.write("a" if rng.random() < 0.6 else "b", msg, t)
    return out


def test_the_overlapping_bag_has_overlapping_chunks(overlapping: Path) -> None:
    with Reader(overlapping) as reader:
        chunks = sorted(reader.storage.storages[0].chunks, key=lambda c: c.message_start_time)  # type: ignore[attr-defined]
    assert len(chunks) > 5
    assert any(a.message_end_time >= b.message_start_time for a, b in zip(chunks, chunks[1:], strict=False))


@pytest.mark.parametrize("name", ["overlapping", "quarter_car_graneville_iso_d_10ms", "lrv_regolith_iso_g_2ms"])
def test_fast_read_gives_rosbags_order(name: str, overlapping: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = overlapping if name == "overlapping" else BAGS / name
    fast = _items(path, True, monkeypatch)
    assert fast == _items(path, False, monkeypatch)
    with Reader(path) as reader:
        assert len(fast) == reader.message_count > 0  # every message, once
    assert name != "overlapping" or len(fast) == 60
    monkeypatch.setattr(bag, "_FAST_READ", True)
    batches = list(read_bag_raw_batches(path))
    assert [(c.topic, t, raw) for b in batches for c, t, raw, _d in b] == fast
    if name == "overlapping":
        assert 1 < len(batches) < len(fast)  # handed out a chunk's worth at a time
