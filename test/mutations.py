"""What the fuzz suites share: valid bytes damaged the ways files and messages get damaged, and the
one-line error they must end in."""

from hypothesis import strategies as st


@st.composite
def damaged(draw, data: bytes, word: int, arbitrary: bool = False) -> bytes:
    """`data` cut short, with bits flipped, or with a `word`-byte field overwritten (lengths and
    counts are 4 or 8 bytes: all ones, all zeros and the largest int32 are the interesting
    values); with `arbitrary`, sometimes any bytes at all."""
    data = bytearray(data)
    kind = draw(st.sampled_from(["cut", "flip", "overwrite", *(["arbitrary"] if arbitrary else [])]))
    if kind == "cut":
        return bytes(data[: draw(st.integers(0, len(data) - 1))])
    if kind == "flip":
        for bit in draw(st.lists(st.integers(0, 8 * len(data) - 1), min_size=1, max_size=4)):
            data[bit // 8] ^= 1 << bit % 8
        return bytes(data)
    if kind == "overwrite":
        at = draw(st.integers(0, len(data) - word))
        largest = (2**31 - 1).to_bytes(word, "little")  # the largest int32, also in an 8-byte field
        data[at: at + word] = draw(st.sampled_from([b"\xff" * word, bytes(word), largest])
                                   | st.binary(min_size=word, max_size=word))
        return bytes(data)
    return draw(st.binary(max_size=300))


def one_line_naming(exc: Exception, *names: str) -> None:
    """The error is one line and names each of `names` (the file, the field)."""
    text = str(exc)
    assert "\n" not in text and "\r" not in text, text
    for name in names:
        assert name in text, (name, text)
