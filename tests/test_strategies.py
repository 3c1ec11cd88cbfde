"""The public Hypothesis strategies generate what their docstrings say."""

from __future__ import annotations

import re

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.judge.requests import validate_request
from conformance.protocol.data_parse import parse_data
from conformance.protocol.data_values import Array, Call, Number
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame
from conformance.spec.checks import allows
from conformance.spec.commands import Param, default_specs
from conformance.suite.strategies import cnts, invalid_kinds, param_values, request_frames
from tests.examples import examples

SPECS = default_specs()
PARAMS: list[Param] = [p for c in SPECS for v in c.variants for p in v.params]
# One strategy for the module: Hypothesis labels a sampled_from by hashing all its
# elements, and these are deep frozen dataclasses (a strategy made per draw cost the
# suite about 3 CPU-s).
PARAM = st.sampled_from(PARAMS)


@settings(max_examples=examples(300), suppress_health_check=[HealthCheck.too_slow])
@given(raw=request_frames(SPECS))
def test_request_frames_are_valid_requests(raw: bytes) -> None:
    (f,) = decode_all(raw, strict=True)
    assert isinstance(f, Frame)
    check = validate_request(f, SPECS, strict=True)
    assert check.ok, [v.detail for v in check.violations]


@settings(max_examples=examples(300))
@given(data=st.data())
def test_param_values_stay_in_their_domain(data: st.DataObject) -> None:
    p = data.draw(PARAM)
    value = data.draw(param_values(p))
    values = value if isinstance(value, list) else [value]
    if p.is_array:
        assert len(values) == p.length
    for x in values:
        assert isinstance(x, (int, float, str)) and allows(p, x), (p.name, x)
        if isinstance(x, float):
            assert round(x, 3) == x  # at most 3 decimals, as the manual writes them


@given(cnt=cnts())
def test_cnts_are_uint16(cnt: int) -> None:
    assert 0 <= cnt <= 0xFFFF


def test_invalid_kinds_only_where_the_table_allows() -> None:
    setdo = SPECS.lookup("SetDO")[0]
    assert set(invalid_kinds(setdo, setdo.variants[0])) == {"count", "type", "range"}
    stop = SPECS.lookup("STOP")[0]
    assert invalid_kinds(stop, stop.variants[0]) == ()


def test_parsed_generated_numbers_keep_their_type() -> None:
    parsed = parse_data("X({1,2.500},3)")
    assert isinstance(parsed, Call)
    first, second = parsed.args
    assert isinstance(first, Array) and isinstance(second, Number) and second.is_int


@given(param_values(Param(name="ip", type="string", quoted=False)))
def test_bare_string_values_are_dotted_quads(value: object) -> None:
    """An unquoted string parameter gets [0-9]{1,3}(.[0-9]{1,3}){3} (without st.from_regex)."""
    assert isinstance(value, str)
    assert re.fullmatch(r"[0-9]{1,3}(\.[0-9]{1,3}){3}", value)
