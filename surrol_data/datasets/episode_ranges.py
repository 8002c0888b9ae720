"""Episode indices as people write them on a command line: ``0,3,5-9`` (commas, inclusive ranges)."""

from __future__ import annotations


def parse_episode_ranges(spec: str) -> list[int]:
    """``"0,3,5-9"`` -> ``[0, 3, 5, 6, 7, 8, 9]`` (order kept, repeats dropped); ValueError saying what is wrong."""
    out: list[int] = []
    for part in (p.strip() for p in str(spec).split(",")):
        if not part:
            continue
        first, dash, last = part.partition("-")
        try:
            lo = int(first)
            hi = int(last) if dash else lo
        except ValueError:
            raise ValueError(f"--episodes takes episode indices and ranges such as 0,3,5-9; {part!r} is neither") \
                from None
        if lo < 0 or hi < lo:
            raise ValueError(f"--episodes: {part!r} is not a range of episode indices (write FIRST-LAST with "
                             "0 <= FIRST <= LAST)")
        out.extend(range(lo, hi + 1))
    if not out:
        raise ValueError(f"--episodes {spec!r} names no episode; write indices and ranges such as 0,3,5-9")
    return list(dict.fromkeys(out))


def chosen_episodes(reader, where: str | None = None, episodes: list[int] | None = None) -> list[int]:
    """Episodes of ``reader`` matching ``where`` (all when None), kept to the indices ``episodes`` when given;
    DatasetError naming any index the dataset does not hold."""
    from surrol_data.datasets.reader import DatasetError

    matching = reader.select(where)
    if episodes is None:
        return matching
    held = set(reader.select())
    absent = [e for e in episodes if e not in held]
    if absent:
        raise DatasetError(f"--episodes: {absent[:10]} are not in {reader.root} (it holds {len(held)} episodes, "
                           f"0-{len(held) - 1})")
    keep = set(matching)
    return [e for e in episodes if e in keep]
