"""Hostile input over HTTP: schemathesis fuzzes every operation of the OpenAPI document that a
live server serves (``GET /v1/openapi.json``, fetched over HTTP), with real requests to that
server.

Each pass runs, per operation, schemathesis's coverage cases (boundary values, missing and
malformed bodies, wrong content types, unexpected methods: a fixed list) and then
hypothesis-generated cases, schema-valid ("positive") and, where the operation takes input
that can be made invalid (the PATCH body), schema-violating ("negative").  Every response must
pass :data:`CHECKS`: never a 5xx (the main bar), the status code documented, the body and the
headers as documented, invalid input refused with a 4xx.  Generation is derandomised, so a run
is reproducible.

``PATCH /v1/config`` also gets bodies no schema can describe: a generated body with one of its
values (or keys) written as JSON Python's parser takes but the daemon refuses (``NaN``,
``Infinity``, ``1e999``, integers past 4300 digits, lone surrogates ``"\ud800"``), sent as raw
bytes; each must be a 400 naming the key.

Passes: a loopback server without a token (everything open), and a server with a token, fuzzed
once without credentials (every protected operation must answer 401, never reach its body) and
once with them (the control endpoints' bodies exercised).  No operation can stop the server
(there is no shutdown endpoint), so none is excluded; ``PATCH /v1/config`` does change it (a
``fit.timeout`` of 5e-324 s is valid and makes every fit "hang"), so the original config is put
back after that operation is fuzzed.

schemathesis's own pytest plug-in (``schemathesis.pytest.from_fixture``) is not used: on pytest
9.2 its lazy loader fails (``'Function' object has no attribute '_nodeid'``).  Driving
hypothesis here takes a few lines and keeps the servers in plain fixtures.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from typing import Any

import hypothesis.strategies as st
import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from schemathesis import Case, GenerationMode
from schemathesis.checks import CHECKS as CHECK_REGISTRY
from schemathesis.checks import load_all_checks
from svc_helpers import http, sim_settings, wait_for

from tactiled.pipeline.daemon import RUNTIME_FIT_KEYS
from tactiled.settings import FIT_FIELDS, MODELS, RUNTIME_SENSOR_KEYS, check_sensor_value

TOKEN = "schemathesis-token-for-tests"
SENSORS = ("finger0", "finger1")
PUBLIC = frozenset({"GET /v1/health", "GET /v1/version"})  # no credentials needed

#: Generated cases per operation and generation mode, besides the coverage cases (every
#: operation's edge values, each run once): the open pass goes deepest; the token server's
#: passes do fewer: without credentials every protected request is the same 401, and with them
#: the point is that the token reaches every body.  ``-m slow``: 20 times more.
MAX_EXAMPLES = 50
MAX_EXAMPLES_ANONYMOUS = 10
MAX_EXAMPLES_AUTHORISED = 25
MAX_EXAMPLES_SLOW = 1000
REQUEST_TIMEOUT_S = 10.0
#: The fingers' frame rate (Hz): what is fuzzed is HTTP, not the frame path, which shares the
#: test's interpreter and at the simulator's 1 kHz took half of each pass's CPU.
RATE_HZ = 100.0
SHARED_RATE_HZ = RATE_HZ  # the module's shared_server (tests/service/conftest.py)

FUZZ_SETTINGS = settings(
    deadline=None,  # a request to a busy server may take a while; that is not a failure
    derandomize=True,  # reproducible: the same cases on every run
    database=None,  # ... and nothing replayed from earlier runs
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    phases=[Phase.explicit, Phase.generate, Phase.shrink],
)

load_all_checks()
#: Every response.  Left out: the checks of stateful runs (use_after_free,
#: ensure_resource_availability), and those about declared security schemes (ignored_auth:
#: the token is not declared, since open loopback servers need none); positive_data_acceptance
#: is added per case (:meth:`Pass.checks_for`).
CHECKS = CHECK_REGISTRY.get_by_names([
    "not_a_server_error",
    "status_code_conformance",
    "content_type_conformance",
    "response_schema_conformance",
    "response_headers_conformance",
    "negative_data_rejection",
    "missing_required_header",
    "unsupported_method",
    "allow_header_conformance",
])
POSITIVE_DATA_ACCEPTANCE = CHECK_REGISTRY.get_by_names(["positive_data_acceptance"])[0]


def figures(test: str, **values: Any) -> None:
    """One line of measured figures (``pytest -rP`` shows it), as tests/reliability prints."""
    print(f"FIGURES {test}: " + json.dumps(values, sort_keys=True, default=str))


class Pass:
    """One schemathesis pass over every operation served by the server at ``base``, sending
    ``headers`` (credentials) with every request; counts what came back."""

    def __init__(self, base: str, headers: dict[str, str] | None = None, *,
                 max_examples: int = MAX_EXAMPLES) -> None:
        self.base = base
        self.headers = dict(headers or {})
        self.settings = settings(FUZZ_SETTINGS, max_examples=max_examples)
        self.schema = schemathesis.openapi.from_url(f"{base}/v1/openapi.json",
                                                    timeout=REQUEST_TIMEOUT_S)
        self.statuses: Counter[int] = Counter()
        self.by_operation: dict[str, Counter[int]] = {}
        self.seconds = 0.0

    # -- what is sent ---------------------------------------------------------------------------

    def strategy(self, operation: Any, mode: GenerationMode) -> st.SearchStrategy[Case]:
        """Cases of ``operation``; a path's sensor ``name`` is also drawn from the real ones
        (random names only ever reach the 404); PATCH bodies also with a hostile literal."""
        cases = operation.as_strategy(generation_mode=mode)
        if "{name}" in operation.path:
            cases = st.one_of(cases, *[
                operation.as_strategy(generation_mode=mode, path_parameters={"name": name})
                for name in SENSORS])
        if operation.label == "PATCH /v1/config":
            cases = st.one_of(cases, st.builds(with_hostile_literal, cases,
                                               st.sampled_from(HOSTILE_LITERALS),
                                               st.integers(0, 40)))
        return cases

    def checks_for(self, case: Case) -> list[Any]:
        """:data:`CHECKS`, plus "a schema-valid request is accepted" (the schema names the
        server's sensors), except for a body made hostile (raw bytes, refused by design)."""
        if is_hostile(case):
            return CHECKS
        return [*CHECKS, POSITIVE_DATA_ACCEPTANCE]

    # -- running --------------------------------------------------------------------------------

    def exercise(self, case: Case) -> None:
        response = case.call(base_url=self.base, headers=self.headers,
                             timeout=REQUEST_TIMEOUT_S)
        label = case.operation.label
        self.statuses[response.status_code] += 1
        self.by_operation.setdefault(label, Counter())[response.status_code] += 1
        case.validate_response(response, checks=self.checks_for(case), headers=self.headers)
        # not_a_server_error says it too; this is the bar, so it is said plainly.
        assert response.status_code < 500, f"{label}: {response.status_code} {response.text}"
        if is_hostile(case) and response.status_code not in (401, 403, 415):
            assert response.status_code == 400, (case.body[:200], response.text)
            detail = response.json()["detail"]
            assert any(w in detail for w in ("surrogate", "JSON number", "double", "digits")), (
                case.body[:200], detail)

    def run(self) -> Pass:
        start = time.monotonic()
        config = http(self.base, "GET", "/v1/config", headers=self.headers)
        for result in self.schema.get_all_operations():
            operation = result.ok()
            self.run_operation(operation)
            if operation.label == "PATCH /v1/config" and config.status_code == 200:
                restored = http(self.base, "PATCH", "/v1/config", json=config.json(),
                                headers=self.headers)
                assert restored.status_code == 200, restored.text
        self.seconds = time.monotonic() - start
        return self

    def run_operation(self, operation: Any) -> None:
        generation = self.schema.config.generation_for(operation=operation, phase="coverage")
        for case in self.schema.iter_coverage_cases(operation, generation_modes=list(
                GenerationMode), generation_config=generation):
            self.exercise(case)
        modes = [GenerationMode.POSITIVE]
        # Every string is a valid path parameter here: only a body or a query can be negated
        # (hypothesis would give up, "Unsatisfiable", after ~500 tries).
        if len(operation.body) or len(operation.query):
            modes.append(GenerationMode.NEGATIVE)
        for mode in modes:
            @self.settings
            @given(case=self.strategy(operation, mode))
            def fuzz(case: Case) -> None:
                self.exercise(case)

            fuzz()

    def report(self, server: str) -> None:
        figures("schemathesis", server=server, operations=len(self.by_operation),
                requests=sum(self.statuses.values()),
                status_counts={str(k): v for k, v in sorted(self.statuses.items())},
                seconds=round(self.seconds, 1))


#: JSON Python's parser takes that the daemon refuses (400 naming the key): non-finite numbers,
#: integers past the int-string limit, lone surrogates (as values, and the first two as keys).
HOSTILE_LITERALS = ('"\\ud800"', '"finger0\\udfff"', "NaN", "Infinity", "-Infinity", "1e999",
                    "-1e999", "9" * 4301, "-" + "7" * 5000, '"a\\udbff\\u0041"')
MARK = "\x00hostile\x00"
_HOSTILE_BODIES: set[bytes] = set()


def is_hostile(case: Case) -> bool:
    """``case``'s body was made by :func:`with_hostile_literal`."""
    return isinstance(case.body, bytes) and case.body in _HOSTILE_BODIES


def with_hostile_literal(case: Case, literal: str, where: int) -> Case:
    """``case`` with its body as raw bytes in which one value (the ``where``-th of its
    containers' slots, in document order; the body itself if it has none) is ``literal``, or
    for a string literal, one key."""
    body = case.body if isinstance(case.body, (dict, list)) else {"fit": {"timeout": 1.0}}
    body = json.loads(json.dumps(body))  # a copy to change
    slots: list[tuple[Any, Any]] = []
    stack = [body]
    while stack:
        node = stack.pop()
        items = list(node.items() if isinstance(node, dict) else enumerate(node))
        for key, value in items:
            slots.append((node, key))
            if isinstance(value, (dict, list)):
                stack.append(value)
    if not slots:
        text = literal
    else:
        node, key = slots[where % len(slots)]
        if literal.startswith('"') and isinstance(node, dict) and where % 2:
            node[MARK] = node.pop(key)  # the key itself
        else:
            node[key] = MARK
        text = json.dumps(body).replace(json.dumps(MARK), literal)
    case.body = text.encode()
    _HOSTILE_BODIES.add(case.body)
    return case


def wait_until_published(base: str, headers: dict[str, str] | None = None) -> None:
    """Until every sensor has an estimate and a frame: before that, their endpoints answer a
    deliberate 503 (Retry-After), which is not what the fuzzing is about."""
    def ready() -> bool:
        return all(http(base, "GET", f"/v1/sensors/{name}/{kind}", headers=headers)
                   .status_code == 200 for name in SENSORS for kind in ("estimate", "frame"))

    wait_for(ready, 60, poll=0.2, what="first estimate and frame of every sensor")


# --------------------------------------------------------------------------------------------
# The passes


def test_fuzz_open_loopback_server(live_server):
    """Loopback without a token: every operation open, every body exercised."""
    server = live_server(sim_settings(len(SENSORS), rate_hz=RATE_HZ))
    wait_until_published(server.url)
    done = Pass(server.url).run()
    done.report("loopback, no token")
    assert len(done.by_operation) == 9, sorted(done.by_operation)  # with GET /metrics
    assert all(200 in counts for counts in done.by_operation.values()), done.by_operation


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_fuzz_open_loopback_server_long(live_server, request):
    """The first pass with 20 times more generated cases (~5 minutes): ``-m slow``."""
    if "slow" not in (request.config.getoption("markexpr") or ""):
        pytest.skip("slow: opt in with -m slow")
    server = live_server(sim_settings(len(SENSORS), rate_hz=RATE_HZ))
    wait_until_published(server.url)
    Pass(server.url, max_examples=MAX_EXAMPLES_SLOW).run().report("loopback, no token, long")


def test_fuzz_token_server_without_and_with_the_token(live_server):
    """With a token: unauthenticated, every protected operation answers 401 whatever the
    input (401 before any validation, never a 5xx); authenticated, every body is exercised."""
    server = live_server(sim_settings(len(SENSORS), rate_hz=RATE_HZ,
                                       **{"server.token": TOKEN}))
    auth = {"Authorization": f"Bearer {TOKEN}"}
    wait_until_published(server.url, auth)

    anonymous = Pass(server.url, max_examples=MAX_EXAMPLES_ANONYMOUS).run()
    anonymous.report("token, no credentials")
    for label, counts in anonymous.by_operation.items():
        if label in PUBLIC:
            assert 200 in counts, (label, counts)
        else:  # 405: the coverage cases' unexpected methods, refused by routing first
            assert set(counts) <= {401, 405} and counts[401] > 0, (label, counts)

    authorised = Pass(server.url, auth, max_examples=MAX_EXAMPLES_AUTHORISED).run()
    authorised.report("token, with the token")
    assert all(200 in counts for counts in authorised.by_operation.values()), (
        authorised.by_operation)


# --------------------------------------------------------------------------------------------
# Regressions: what the fuzzing found, kept as plain tests


def test_405_allow_lists_every_method_of_the_path(shared_server):
    """Found by allow_header_conformance: ``OPTIONS /v1/config`` answered 405 with
    ``Allow: GET`` (Starlette names the first route's methods; PATCH is another route)."""
    for method in ("OPTIONS", "DELETE", "PUT"):
        r = http(shared_server.url, method, "/v1/config")
        assert r.status_code == 405 and r.headers["allow"] == "GET, PATCH", (method, r.headers)
        assert r.json() == {"detail": "Method Not Allowed"}
    r = http(shared_server.url, "PUT", "/v1/sensors/finger0/tare")
    assert r.status_code == 405 and r.headers["allow"] == "POST"


def config_patch_schema(base: str) -> dict[str, Any]:
    spec = http(base, "GET", "/v1/openapi.json").json()
    assert "413" in spec["paths"]["/v1/config"]["patch"]["responses"]  # body over 64 KiB
    content = spec["paths"]["/v1/config"]["patch"]["requestBody"]["content"]
    assert content["application/json"] == content["application/merge-patch+json"]
    return content["application/json"]["schema"]


def test_config_patch_schema_documents_what_the_daemon_accepts(shared_server):
    """Found by positive_data_acceptance: the PATCH body was documented as free-form objects,
    ``null`` allowed (``{"fit": null}`` is a 422).  It now lists the run-time keys with the
    daemon's own bounds; this keeps the two in step (the same keys, the enum, and each bound
    accepted or refused by the daemon's field checks as the schema says).  The sensors are the
    server's own, by name (a generated request never names one the daemon does not have)."""
    schema = config_patch_schema(shared_server.url)
    assert set(schema["properties"]) == {"sensors", "fit"}
    assert schema["additionalProperties"] is False
    sensors = schema["properties"]["sensors"]
    assert sensors["propertyNames"] == {"enum": list(SENSORS)}
    assert list(sensors["properties"]) == list(SENSORS)
    assert sensors["additionalProperties"] is False
    sensor = sensors["properties"]["finger0"]
    assert sensors["properties"]["finger1"] == sensor
    fit = schema["properties"]["fit"]
    assert set(sensor["properties"]) == set(RUNTIME_SENSOR_KEYS)
    assert set(fit["properties"]) == set(RUNTIME_FIT_KEYS)
    assert sensor["properties"]["model"]["enum"] == list(MODELS)
    assert "null" not in json.dumps(schema)

    def accepted(section: str, key: str, value: Any) -> bool:
        check = FIT_FIELDS[key] if section == "fit" else (
            lambda v, where: check_sensor_value(key, v, where))
        try:
            check(value, key)
        except Exception:
            return False
        return True

    for section, part in (("sensors", sensor), ("fit", fit)):
        for key, prop in part["properties"].items():
            for bound, inside in (("minimum", True), ("maximum", True),
                                  ("exclusiveMinimum", False), ("exclusiveMaximum", False)):
                if bound in prop:
                    # The served document writes every bound as a float (2.0).
                    value = int(prop[bound]) if prop["type"] == "integer" else prop[bound]
                    assert accepted(section, key, value) is inside, (key, bound, prop)
    for body in ({"fit": None}, {"sensors": None}, {"sensors": {"finger0": None}},
                 {"sensors": {"finger0": {"model": None}}}, {"other": {}},
                 {"sensors": {"finger9": {"model": "auto"}}}):
        r = http(shared_server.url, "PATCH", "/v1/config", json=body)
        assert r.status_code == 422, (body, r.text)


def test_integral_json_number_is_an_integer(shared_server):
    """Found by positive_data_acceptance: ``"window": 185.0`` is an integer to JSON Schema
    (the documented type) but was refused, 422 "expected an integer, got 185.0"."""
    base = shared_server.url
    before = http(base, "GET", "/v1/config").json()
    try:
        r = http(base, "PATCH", "/v1/config", content=b'{"sensors": {"finger0": {"window": '
                 b'6.0, "unchanged_z": 4}}}', headers={"Content-Type": "application/json"})
        assert r.status_code == 200, r.text
        finger0 = r.json()["sensors"]["finger0"]
        assert finger0["window"] == 6 and finger0["unchanged_z"] == 4.0
        r = http(base, "PATCH", "/v1/config", json={"sensors": {"finger0": {"window": 6.5}}})
        assert r.status_code == 422 and "window" in r.json()["detail"], r.text
    finally:
        http(base, "PATCH", "/v1/config", json=before)


def test_refused_config_patch_changes_nothing(shared_server):
    """Found by positive_data_acceptance: ``false_rate: 1e-300`` passed the settings check,
    then the detector raised (422 "p must be in the range 0.0 < p < 1.0") half-way through the
    PATCH, and what came before it stayed applied (finger0's model here; finger1's settings
    recorded the refused value).  Fixed upstream (6f5de66: the range is 1e-12..0.5, and a
    failure while applying rolls back); the refusal now changes nothing."""
    base = shared_server.url
    before = http(base, "GET", "/v1/config").json()
    try:
        for false_rate in (1e-300, 1e-15):
            r = http(base, "PATCH", "/v1/config", json={
                "sensors": {"finger0": {"model": "sphere"},
                            "finger1": {"false_rate": false_rate}}})
            assert r.status_code == 422 and "false_rate" in r.json()["detail"], r.text
            assert http(base, "GET", "/v1/config").json() == before
    finally:
        http(base, "PATCH", "/v1/config", json=before)
