"""Hypothesis against the one JSON decoder (:func:`tactiled_service.inbound.decode_json`) and
through it against a live server: JSON texts built with lone surrogates (in keys and values),
integers around Python's 4300-digit limit, ``NaN``/``Infinity``/``1e999`` and deep nesting.

* The decoder alone, against an independent oracle (the standard library's parser plus a
  check of what it returned): a text is refused exactly when it holds something the daemon
  cannot represent, with a message that encodes; otherwise it decodes to what the standard
  parser gives.
* A real server on 127.0.0.1: every generated stream message gets a reply and the connection
  answers a ping after it; every generated ``PATCH /v1/config`` body gets a 2xx/4xx whose
  detail encodes; no record of the server's log carries a traceback.
"""

from __future__ import annotations

import json
import logging
import math
from typing import Any

import hypothesis.strategies as st
from hypothesis import HealthCheck, assume, given, settings
from svc_helpers import http
from websockets.sync.client import connect

from tactiled_service.inbound import MAX_DEPTH, MAX_INT_DIGITS, BadJson, decode_json

FUZZ = settings(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
#: The shared server's frame rate (Hz; tests/service/conftest.py): what is fuzzed is the
#: parsing of messages and bodies, not the frame path, which shares the test's interpreter.
SHARED_RATE_HZ = 100.0

# -- JSON texts ---------------------------------------------------------------------------------

#: Any code point, lone surrogates included (json.dumps writes those as \\udXXX escapes).
CHARS = st.one_of(st.characters(), st.integers(0xD800, 0xDFFF).map(chr))
STRINGS = st.text(CHARS, max_size=6).map(json.dumps)
KEYS = st.one_of(STRINGS, st.sampled_from(["type", "id", "sensors", "finger0", "fit", "timeout",
                                           "max_rate", "streams", "model"]).map(json.dumps))
NUMBERS = st.one_of(
    st.integers().map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.sampled_from(["NaN", "Infinity", "-Infinity", "1e999", "-1e400", "1E+309", "0.5e-400"]),
    # either side of the int-string limit
    st.integers(MAX_INT_DIGITS - 2, MAX_INT_DIGITS + 2).map(lambda n: "9" * n),
    st.integers(MAX_INT_DIGITS - 2, MAX_INT_DIGITS + 2).map(lambda n: "-" + "8" * n),
)
SCALARS = st.one_of(st.sampled_from(["null", "true", "false"]), NUMBERS, STRINGS)
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=4).map(lambda xs: "[" + ",".join(xs) + "]"),
    st.lists(st.tuples(KEYS, inner), max_size=4).map(
        lambda kv: "{" + ",".join(f"{k}:{v}" for k, v in kv) + "}")), max_leaves=8)
DEEP = st.integers(MAX_DEPTH - 2, MAX_DEPTH + 2).map(lambda n: "[" * n + "1" + "]" * n)
TEXTS = st.one_of(VALUES, DEEP)
MESSAGES = st.builds(
    lambda kind, fields: "{" + ",".join([f'"type":{kind}', *(f"{k}:{v}" for k, v in fields)])
    + "}",
    st.one_of(st.sampled_from(['"ping"', '"subscribe"', '"unsubscribe"']), SCALARS),
    st.lists(st.tuples(KEYS, st.one_of(VALUES, DEEP)), max_size=3))


def representable(value: Any, depth: int = 0) -> bool:
    """What the daemon can hold and echo: finite numbers, Unicode strings (no lone
    surrogate), nesting within MAX_DEPTH.  The oracle's half that is not the standard parser."""
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, str):
        return not any(0xD800 <= ord(c) <= 0xDFFF for c in value)
    if isinstance(value, (dict, list)):
        if depth >= MAX_DEPTH:
            return False
        items = value.items() if isinstance(value, dict) else enumerate(value)
        return all((isinstance(k, int) or representable(k)) and representable(v, depth + 1)
                   for k, v in items)
    return True


@FUZZ
@given(text=st.one_of(TEXTS, MESSAGES))
def test_decoder_refuses_exactly_what_cannot_be_represented(text):
    try:
        expected = json.loads(text)  # takes NaN, 1e999 (inf), surrogates; raises past 4300
        ok = representable(expected)
    except ValueError:  # the int-string limit
        ok = False
    try:
        got = decode_json(text, "message")
    except BadJson as err:
        assert not ok, (text[:200], str(err))
        str(err).encode("utf-8")  # the message always encodes
        assert str(err).startswith(err.where + ": ")
        return
    assert ok, text[:200]
    assert got == expected
    json.dumps(got, allow_nan=False, ensure_ascii=False).encode("utf-8")


@FUZZ
@given(text=TEXTS)
def test_bytes_decode_like_text(text):
    """A body (bytes) and a stream message (text) take the same path to the same outcome."""
    outcomes = []
    for data in (text, text.encode("utf-8")):
        try:
            outcomes.append(("value", decode_json(data)))
        except BadJson as err:
            outcomes.append(("refused", str(err)))
    assert outcomes[0] == outcomes[1]


# -- through a live server ------------------------------------------------------------------------


def assert_no_traceback(caplog) -> None:
    bad = [r for r in caplog.records if r.exc_info or "Traceback" in r.getMessage()]
    assert not bad, [r.getMessage() for r in bad]


def test_stream_replies_to_every_generated_message(shared_server, caplog):
    caplog.set_level(logging.WARNING)
    counter = iter(range(10**9))
    with connect(shared_server.ws_url, compression=None, open_timeout=10,
                 max_size=2**22) as ws:
        assert json.loads(ws.recv(10))["type"] == "version"

        @settings(FUZZ, max_examples=150)
        @given(text=MESSAGES)
        def exchange(text: str) -> None:
            # ASCII: json.dumps escapes the rest; the 64 KiB message limit closes with 1009
            # (tested elsewhere)
            assume(len(text) < 60_000)
            probe = f"probe-{next(counter)}"
            ws.send(text)
            ws.send(json.dumps({"type": "ping", "id": probe}))
            replies = []
            while True:
                msg = json.loads(ws.recv(10))
                if msg["type"] == "pong" and msg["id"] == probe:
                    break
                if msg["type"] not in ("estimate", "frame"):
                    replies.append(msg)
            assert len(replies) == 1, (text[:200], replies)
            reply = replies[0]
            assert reply["type"] in ("error", "pong", "subscribed", "unsubscribed"), reply
            if reply["type"] == "error":
                assert reply["code"] in ("bad_message", "unknown_sensor"), reply
            ws.send('{"type": "unsubscribe"}')
            while json.loads(ws.recv(10))["type"] != "unsubscribed":
                pass

        exchange()
    assert_no_traceback(caplog)


def test_config_patch_answers_every_generated_body(shared_server, caplog):
    caplog.set_level(logging.WARNING)
    base = shared_server.url
    before = http(base, "GET", "/v1/config").json()
    statuses: dict[int, int] = {}
    try:
        @settings(FUZZ, max_examples=150)
        @given(text=st.one_of(TEXTS, st.builds(lambda v: '{"sensors": {"finger0": ' + v + "}}",
                                               VALUES)))
        def exchange(text: str) -> None:
            r = http(base, "PATCH", "/v1/config",
                     content=text.encode(),
                     headers={"Content-Type": "application/json"})
            statuses[r.status_code] = statuses.get(r.status_code, 0) + 1
            assert r.status_code in (200, 400, 413, 422), (text[:200], r.status_code, r.text)
            if r.status_code == 200:
                http(base, "PATCH", "/v1/config", json=before)
            else:
                assert r.json()["detail"], r.text

        exchange()
    finally:
        http(base, "PATCH", "/v1/config", json=before)
    print("FIGURES json_fuzz_patch: " + json.dumps(statuses, sort_keys=True))
    assert statuses.get(400, 0) > 0 and statuses.get(422, 0) + statuses.get(200, 0) > 0
    assert_no_traceback(caplog)
