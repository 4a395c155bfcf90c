"""Group patterns through the library (issue 35): ``exclude=5`` raised TypeError (bytes and
dicts iterated as numbers and keys); a pattern that matches nothing now lists the names the
file has, says when a ``kind:`` prefix is no kind or the file has no names of that kind,
and names the names a case-insensitive match would find.  (The CLI's --exclude is being
fixed elsewhere: these go through the library.)"""

from __future__ import annotations

import pytest

import aobake


@pytest.fixture
def named(tmp_path):
    """An OBJ with objects 'floor' and 'box' (25 more objects 'extra_k') and group 'lid'."""
    lines, k = [], 0
    for name in ["floor", "box"] + [f"extra_{i:02d}" for i in range(25)]:
        lines.append(f"o {name}")
        if name == "box":
            lines.append("g lid")
        z = float(len(lines))
        lines += [f"v 0 0 {z}", f"v 1 0 {z}", f"v 0 1 {z}", f"f {k + 1} {k + 2} {k + 3}"]
        k += 3
    path = tmp_path / "named.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("value", [5, 2.5, b"floor", {"floor": 1}, object()])
def test_a_pattern_that_is_no_text_is_an_input_error(named, value):
    with pytest.raises(aobake.InputError, match="exclude takes a name pattern"):
        aobake.bake(named, exclude=value, rays=2)
    with pytest.raises(aobake.InputError, match="receive_only takes a name pattern"):
        aobake.BakeConfig(receive_only=value)


def test_a_pattern_or_a_list_of_them_is_taken(named):
    for value in ("floor", ["floor"], ("floor", "box"), None):
        assert aobake.bake(named, exclude=value, rays=2).ao is not None


def _error(named, pattern):
    with pytest.raises(aobake.InputError) as info:
        aobake.bake(named, exclude=pattern, rays=2)
    message = str(info.value)
    assert message.startswith(f"{named}: --exclude {pattern!r} matches no face's name (")
    return message


def test_no_match_lists_the_names_and_how_many_more(named):
    message = _error(named, "zzz")
    assert "object 'floor', 'box', 'extra_00'" in message and "group 'lid'" in message
    assert "and 7 more" in message  # 27 objects, 20 listed


def test_no_match_explains_prefixes_and_case(named):
    assert "'obj' is not a kind of name" in _error(named, "obj:floor")
    assert "it gives no face a material name" in _error(named, "material:floor")
    assert "ignoring case it would match 'floor'" in _error(named, "FLOOR")
