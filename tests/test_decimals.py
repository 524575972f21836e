"""The fast decimal reader against Python's float() (correctly rounded, David Gay's strtod), bit
for bit: awkward hand-picked numbers, random ones, tokens that are not plain decimals, and a
blank-separated file read by the delimited parser."""
from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.protocols.decimals import plain_decimals
from drivers.protocols.delimited import ChannelMap, DelimitedTextParser

# Inside the fast path: at most 18 digits, mantissa <= 2^53, |decimal exponent| <= 22.
AWKWARD = [
    "0", "-0", "+0", "-0.0", "0e0", "-0e-5", "7", "-7", "+7", "007", "-00.250", "00000000000000001",
    ".5", "-.5", "+.5", "5.", "-5.", "1.e5", "1E+05", "1e-05", "3.3108000e+04", "2.9840000e-02",
    "-1.234e+02", "0.1", "0.2", "0.3", "-0.3", "1.1", "2.675", "123456789012345",
    "9007199254740992", "9007199254740991e-22", "4.35679e-17", "1e22", "1e-22", "-9.87654321e+10",
    "1234567.1234567", "0.000001", "8999999999999.999", "8.98846567431158e+07", "5e-1",
    "1.797693134862315e+8", "2.225073858507201e-7", "0.000000000000001", "-1e+0022",
]
# Plain decimals outside the fast path: the caller falls back to strtod.
SLOW = ["9007199254740993", "1234567890123456789", "1e23", "1e-23", "1.7976931348623157e308",
        "4.9e-324", "0.1000000000000000055511151231257827", "4.35679e-22", "99999999999999.99",
        "2.2250738585072014e-8", "0.000000000000000000001", "0.30000000000000004"]
NOT_PLAIN = ["1-2", "1..5", "1e", "1e+", "+", "-", ".", "e5", "-e5", ".e5", "1e5e3", "1e+-5",
             "--1", "+-1", "1.5.", "1e5.3", "1.2.3", "1+", "1e5-"]


def bits(values) -> list[int]:
    return np.asarray(values, dtype=np.float64).view(np.int64).tolist()


def text(tokens: list[str], blanks: str = " ") -> bytes:
    return (blanks.join(tokens) + "\n").encode("ascii")


def test_awkward_numbers_are_read_bit_for_bit_as_float_does():
    got = plain_decimals(text(AWKWARD))
    assert got is not None  # all of them in the fast path
    assert bits(got) == bits([float(t) for t in AWKWARD])
    assert np.signbit(got[AWKWARD.index("-0")]) and np.signbit(got[AWKWARD.index("-0e-5")])


@pytest.mark.parametrize("token", SLOW)
def test_numbers_beyond_exact_scaling_are_left_to_strtod(token):
    assert plain_decimals(text(["1.5", token, "2"])) is None


@pytest.mark.parametrize("token", NOT_PLAIN)
def test_a_token_that_is_not_one_plain_decimal_is_refused(token):
    assert plain_decimals(text(["1.5", token, "2"])) is None
    assert plain_decimals(text([token])) is None


def test_tabs_crlf_runs_of_blanks_and_a_leading_token():
    tokens = ["-1.5", "2e3", "+.25", "7"]
    got = plain_decimals(b"-1.5\t\t2e3 \r\n   +.25\t7\r\n")
    assert bits(got) == bits([float(t) for t in tokens])
    assert plain_decimals(b"\n  \n").size == 0


@st.composite
def decimals(draw):
    """A plain decimal of up to 18 digits, with or without point and exponent, and its text."""
    digits = draw(st.text("0123456789", min_size=1, max_size=17))
    point = draw(st.integers(-1, len(digits)))  # -1: no point
    mantissa = digits if point < 0 else digits[:point] + "." + digits[point:]
    sign = draw(st.sampled_from(["", "-", "+"]))
    letter = draw(st.sampled_from(["", "e", "E"]))
    exponent = ""
    if letter:
        e = draw(st.integers(-30, 30))
        exponent_sign = "-" if e < 0 else draw(st.sampled_from(["", "+"]))
        exponent = f"{letter}{exponent_sign}{abs(e):0{draw(st.integers(1, 3))}d}"
    return sign + mantissa + exponent


@settings(max_examples=300, deadline=None)
@given(st.lists(decimals(), min_size=1, max_size=40))
def test_random_decimals_are_float_bit_for_bit_or_refused(tokens):
    """Either every token is read exactly as float() reads it, or the whole text is refused
    (and then one token at least is outside the fast path)."""
    got = plain_decimals(text(tokens))
    singles = [plain_decimals(text([t])) for t in tokens]
    if got is None:
        assert any(s is None for s in singles)
    else:
        assert bits(got) == bits([float(t) for t in tokens])
    for t, s in zip(tokens, singles):
        assert s is None or bits(s) == bits([float(t)])


PLAIN_DECIMAL = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


@settings(max_examples=500, deadline=None)
@given(st.text(" \t\r\n0123456789+-.eE", max_size=60).map(lambda s: s + "\n"))
def test_any_mix_of_number_bytes_is_read_as_float_does_or_refused(soup):
    """Every string of blanks and number bytes: a token that is not one plain decimal means
    None; when the result is not None, it is float() of every token, bit for bit."""
    tokens = soup.split()
    got = plain_decimals(soup.encode("ascii"))
    if not all(PLAIN_DECIMAL.fullmatch(t) for t in tokens):
        assert got is None
    elif got is not None:
        assert bits(got) == bits([float(t) for t in tokens])


def test_text_without_a_blank_at_its_end_is_refused():
    assert plain_decimals(b"1.5 2") is None and plain_decimals(b"").size == 0


def test_short_decimals_are_always_read_by_exact_scaling():
    """Up to 15 significant digits, magnitudes 1e-7 .. 1e8 (the usual log, %g or %e written) are
    never refused: the common case the importer reads this way. The decimal exponent stays within ±22."""
    rng = np.random.default_rng(7)
    x = rng.choice([-1, 1], 3000) * rng.uniform(1, 10, 3000) * 10.0 ** rng.integers(-7, 9, 3000)
    p = rng.integers(1, 15, 3000)
    tokens = ([f"{v:.{p}g}" for v, p in zip(x[:1000], p)] + [f"{v:.{p}e}" for v, p in zip(x[1000:2000], p)]
              + [f"{v:.{p % 7}f}" for v, p in zip(x[2000:], p)])  # at most 9 + 6 digits
    got = plain_decimals(text(tokens, " \t"))
    assert got is not None and bits(got) == bits([float(t) for t in tokens])


def test_the_whitespace_parser_reads_awkward_numbers_as_float_does():
    """Through DelimitedTextParser: lines of awkward numbers (the whole-block path) and a block
    with numbers outside the fast path (the fallback) both give float()'s bits."""
    cm = ChannelMap(triads={"a": (1, 2, 3)}, delimiter=None, time_column=0)
    for pool in (AWKWARD, AWKWARD + SLOW):
        rows = [[str(i), *(pool[(3 * i + k) % len(pool)] for k in range(3))] for i in range(60)]
        chunk = DelimitedTextParser(cm).feed(("\n".join("  ".join(r) for r in rows) + "\n").encode(), 0.0)
        assert bits(chunk.triads["a"]) == bits([[float(x) for x in r[1:]] for r in rows])
        assert bits(chunk.t) == bits([float(r[0]) for r in rows])


@st.composite
def rows_of_fields(draw):
    """Rows of the same number of short tokens, a point in one field of every row (the usual
    log: time then counts), and now and then a row that breaks the pattern: a point in another
    field or none, two points, a lone sign or point, a long token."""
    fields = draw(st.integers(1, 5))
    with_point = draw(st.integers(0, fields - 1))
    number = st.builds(lambda sign, whole, frac: f"{sign}{whole}", st.sampled_from(["", "-", "+"]),
                       st.text("0123456789", min_size=1, max_size=7), st.none())
    fixed = st.builds(lambda sign, whole, frac: f"{sign}{whole}.{frac}", st.sampled_from(["", "-", "+"]),
                      st.text("0123456789", max_size=6), st.text("0123456789", max_size=7))
    odd = st.sampled_from(["-", ".", "+.", "-.5", "5.", "1.2.3", "1..2", "--1", "1-2", "0.1234567890123456",
                           "1234567890123456", "12345.678901234", "-0", "-0.0", "007"])
    rows = []
    for _ in range(draw(st.integers(1, 8))):
        row = [draw(fixed if k == with_point else number) for k in range(fields)]
        if draw(st.integers(0, 5)) == 0:
            row[draw(st.integers(0, fields - 1))] = draw(odd | fixed | number)
        rows.append(row)
    return fields, rows


@settings(max_examples=200, deadline=None)
@given(rows_of_fields(), st.sampled_from([" ", "\t", "  "]))
def test_rows_of_short_fields_read_as_float_does_with_or_without_the_rows_hint(case, blank):
    """The rows hint (the points' field found, not searched) changes nothing: the same values as
    without it and as float(), bit for bit, or None for the same texts."""
    fields, rows = case
    data = "".join(blank.join(row) + "\n" for row in rows).encode("ascii")
    hinted, plain = plain_decimals(data, fields=fields), plain_decimals(data)
    assert (hinted is None) == (plain is None)
    tokens = [t for row in rows for t in row]
    if all(PLAIN_DECIMAL.fullmatch(t) for t in tokens) and max(map(len, tokens)) <= 15:
        assert hinted is not None and bits(hinted) == bits([float(t) for t in tokens])
    if plain is not None:
        assert bits(hinted) == bits(plain)


@pytest.mark.parametrize("data", [b"+.\n", b"-.\n", b"-\n", b".\n", b"1.5 -.\n2.5 7\n"])
def test_a_token_with_no_digit_is_refused_on_the_short_path_too(data):
    assert plain_decimals(data, fields=2 if data.count(b"\n") == 2 else 1) is None


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80).map(lambda b: b + b"\n"))
def test_blank_runs_are_the_solid_runs_of_the_blank_mask(data):
    from drivers.protocols.decimals import blank_runs, solid_runs

    a = np.frombuffer(data, dtype=np.uint8)
    blank, start, stop = blank_runs(a)
    expected = solid_runs(a <= 32)
    assert blank.tolist() == (a <= 32).tolist()
    assert start.tolist() == expected[0].tolist() and stop.tolist() == expected[1].tolist()


# Fixed-width lines (fixed_width_decimals): read by columns, the same bits as float().
FIXED = [b"0.029840 33108 33329 36429\n1.039857 33096 33336 36437\n",  # imu_tk's layout, savetxt("%.6f %d")
         b"-1.50 +2 -0.00\n12.50 -3 +9.99\n",  # a sign or a digit leads a field
         b".5 5.\r\n.7 8.\r\n",  # no digit before or after the point; CRLF
         b"-0.000\t7\n+1.250\t8\n",  # tab, -0
         b"  123456789012345  -1.0000000000001\n  999999999999999  +9.9999999999999\n",  # 15 columns
         b"   2.9840000e-02   3.3108000e+04\n   3.9857000e-02  -3.3096000E+04\n",  # imu_tk's own, %15.7e
         b"1e5 2.5E-3 -.5e+1\n2e6 7.5e22 +.7e-9\n", b"1.e0\n2.e9\n",
         b"-1.5e+00 -2\n 1.5e+00  3\n",  # right-aligned: a blank where the first line has a sign
         b"  1.5e+00   2\n -1.5e+00  -3\n",  # ... and a sign where it has a blank
         b"1.5e+00 2.25 3 -0.5\n2.5e-01 7.75 4 +1.0\n"]  # an exponent, fractions and a count: each field its own scale
NOT_FIXED = [b"1 2\n1  2\n",  # the separators move
             b"1.5 2\n15. 2\n",  # the point moves
             b"1-2\n1-3\n", b"1+2\n1+3\n", b"1e5-\n1e5-\n",  # a sign inside
             b"1e+\n2e+\n", b"1e.5\n2e.5\n", b"e5\ne6\n", b"1e1e1\n", b"1e1234\n",  # no exponent digit...
             b"1.0e30\n1.0e22\n", b"1.5e-23\n1.5e-22\n",  # beyond exact scaling
             b"  -1\n --1\n", b"  -1\n -+1\n", b"1  -5\n1 - 5\n", b"-12\n  2\n",  # two signs, a sign apart
             b"1e+5\n1e 5\n", b"1  5\n1 25\n", b"1  5\n1 x5\n",  # a blank in an exponent; a digit, a letter in a blank
             b"- 1\n- 2\n", b"+. 1\n-. 2\n",  # a sign or point with no digit
             b"1234567890123456\n", b"1.2.3\n", b"ab\ncd\n", b"#1\n#2\n", b"\n\n",
             b"1 2\n3\x0b4\n", b"1 2\n3\x004\n", b"1 2\n3 4", b"1 2\n3 4\n5\n"]


@pytest.mark.parametrize("data", FIXED)
def test_fixed_width_lines_are_read_by_columns_as_float_does(data):
    from drivers.protocols.decimals import fixed_width_decimals

    lines = data.decode().splitlines()
    got = fixed_width_decimals(data, len(lines))
    assert got is not None and got.shape == (len(lines), len(lines[0].split()))
    assert bits(got.ravel()) == bits([float(t) for t in data.split()])
    assert np.signbit(got.ravel()).tolist() == [t.startswith(b"-") for t in data.split()]


@pytest.mark.parametrize("data", NOT_FIXED)
def test_lines_not_alike_or_not_plain_are_left_to_the_token_reader(data):
    from drivers.protocols.decimals import fixed_width_decimals

    assert fixed_width_decimals(data, data.count(b"\n")) is None


@st.composite
def fixed_width_rows(draw):
    """Rows of fields each written to its own fixed width (as a logger's printf does): digits
    before and after a point at fixed places, a sign or a digit first, now and then a byte of
    another kind somewhere (a letter, a second point, an exponent, a blank); exponents of
    fixed width in some fields."""
    fields = [(draw(st.integers(0, 7)), draw(st.integers(-1, 8)), draw(st.booleans()), draw(st.integers(-1, 2)))
              for _ in range(draw(st.integers(1, 5)))]  # digits before the point, after it (-1: none), signed,
    # exponent digits (-1: no exponent)
    rows = []
    for _ in range(draw(st.integers(1, 6))):
        row = []
        for whole, after, signed, exponent in fields:
            lead = draw(st.sampled_from("-+0123456789")) if signed else ""
            text = lead + draw(st.text("0123456789", min_size=whole, max_size=whole))
            if after >= 0:
                text += "." + draw(st.text("0123456789", min_size=after, max_size=after))
            text = text or "0"
            if exponent >= 0:
                text += draw(st.sampled_from("eE")) + draw(st.sampled_from("+-0123456789")) + draw(
                    st.text("0123456789", min_size=exponent, max_size=exponent))
            row.append(text)
        line = draw(st.sampled_from([" ", "\t", "  "])).join(row)
        if draw(st.integers(0, 6)) == 0 and line:
            at = draw(st.integers(0, len(line) - 1))
            line = line[:at] + draw(st.sampled_from(["x", ".", "e", " ", "-"])) + line[at + 1:]
        rows.append(line)
    return rows


@settings(max_examples=200, deadline=None)
@given(fixed_width_rows(), st.sampled_from(["\n", "\r\n"]))
def test_fixed_width_rows_are_float_bit_for_bit_or_left_to_the_token_reader(rows, end):
    """Whatever the rows: None, or every token as float() reads it, bit for bit; and rows of
    one layout with only plain decimals of at most 15 digits are always read by columns."""
    from drivers.protocols.decimals import fixed_width_decimals

    data = "".join(row + end for row in rows).encode("ascii")
    got = fixed_width_decimals(data, len(rows))
    tokens = data.split()
    plain = all(PLAIN_DECIMAL.fullmatch(t.decode()) for t in tokens)
    if got is not None:
        assert plain and bits(got.ravel()) == bits([float(t) for t in tokens])
    plain = plain and not any(b"e" in t.lower() for t in tokens)  # (an exponent may be beyond exact scaling)
    alike = len({r.replace("\t", " ").translate(str.maketrans("0123456789+-", "0" * 12)) for r in rows}) == 1
    if plain and alike and all(len(t.replace(b".", b"").lstrip(b"+-")) <= 15 for t in tokens) \
            and all(len(t) > 1 or t.isdigit() for t in tokens) and not any(t in (b"+.", b"-.") for t in tokens):
        assert got is not None


def test_the_whitespace_parser_reads_fixed_width_lines_by_columns_as_token_by_token(monkeypatch):
    """A block of alike lines takes the column reader (counted); its chunk is the one the token
    reader makes of the same text, bit for bit, and float()'s."""
    import drivers.protocols.delimited as delimited

    rows = [f"{0.01 * i:9.6f} {33000 + 7 * i:5d} {-1.25 * (i % 3):+.3f} {i % 10}" for i in range(200)]
    data = ("\n".join(rows) + "\n").encode()
    assert len({len(r) for r in rows}) == 1
    cm = ChannelMap(triads={"a": (1, 2, 3)}, delimiter=None, time_column=0)
    calls = []
    by_columns = delimited.fixed_width_decimals
    monkeypatch.setattr(delimited, "fixed_width_decimals", lambda *a: calls.append(1) or by_columns(*a))
    fixed = DelimitedTextParser(cm).feed(data, 0.0)
    monkeypatch.setattr(delimited, "fixed_width_decimals", lambda *a: None)
    tokens = DelimitedTextParser(cm).feed(data, 0.0)
    assert calls == [1]
    assert bits(fixed.t) == bits(tokens.t) == bits([float(r.split()[0]) for r in rows])
    assert bits(fixed.triads["a"]) == bits(tokens.triads["a"]) == bits([[float(x) for x in r.split()[1:]] for r in rows])


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.sampled_from("ef"), st.integers(0, 9), st.integers(0, 4)), min_size=1, max_size=4),
       st.lists(st.lists(st.floats(-1e8, 1e8), min_size=4, max_size=4), min_size=1, max_size=6),
       st.none() | st.tuples(st.integers(0, 10_000), st.sampled_from(" -+.e5")))
def test_printf_right_aligned_rows_are_read_as_float_does(formats, rows, damage):
    """Rows as printf writes them right-aligned ("%15.7e", "%12.4f": a negative number's sign
    in the blank a positive one leaves) are read, bit for bit as float(); a byte changed
    anywhere gives float()'s bits or None, never other numbers."""
    from drivers.protocols.decimals import fixed_width_decimals

    lines = [" ".join(f"{v:>{8 + pad + digits}.{digits}{kind}}" for (kind, digits, pad), v in zip(formats, row))
             for row in rows]
    data = bytearray("".join(line + "\n" for line in lines).encode("ascii"))
    if damage is not None and len(data) > 1:
        at = damage[0] % (len(data) - 1)
        data[at] = 10 if data[at] == 10 else ord(damage[1])
    data = bytes(data)
    got = fixed_width_decimals(data, data.count(b"\n"))
    if got is not None:
        assert bits(got.ravel()) == bits([float(t) for t in data.split()])
    elif damage is None and len({line.translate(_SIGN_AS_BLANK) for line in lines}) == 1:  # one layout
        assert not all(_exactly_scaled(t.decode()) for t in data.split())


_SIGN_AS_BLANK = str.maketrans("0123456789+-", "0000000000  ")


def _exactly_scaled(token: str) -> bool:
    """At most 15 mantissa columns (a sign counted: other lines may have a digit there) and a
    power of ten within ±22: Clinger's exact case, as the column reader takes it."""
    mantissa, _, exponent = token.lower().partition("e")
    whole, _, fraction = mantissa.partition(".")
    return len(whole + fraction) <= 15 and abs(int(exponent or 0) - len(fraction)) <= 22
