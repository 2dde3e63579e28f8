"""deploy/tactiled.service and deploy/99-tactiled.rules: required directives, consistency with
the example config, `systemd-analyze verify` / `security`, and the daemon under MemoryDenyWriteExecute."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from deploy_helpers import ROOT

UNIT = ROOT / "deploy" / "tactiled.service"
RULES = ROOT / "deploy" / "99-tactiled.rules"
CONFIG = ROOT / "deploy" / "tactiled.toml"
DOCS = ROOT / "docs" / "howto" / "deploy.md"
INSTALLED_EXEC = "/opt/tactiled/.venv/bin/tactiled"
SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
MAX_EXPOSURE = 2.0  # docs/howto/deploy.md quotes the score; hardening must not silently regress


def parse_unit(text: str) -> dict[str, list[tuple[str, str]]]:
    """Sections -> [(key, value)] in order; keys may repeat (DeviceAllow=, Environment=), which
    configparser cannot represent.  Comments start with # or ;.  No line continuations used."""
    sections: dict[str, list[tuple[str, str]]] = {}
    current = None
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        assert not line.endswith("\\"), f"line {n}: continuation lines are not expected"
        if line.startswith("["):
            assert line.endswith("]"), f"line {n}: bad section header {line!r}"
            current = sections.setdefault(line[1:-1], [])
            continue
        assert current is not None and "=" in line, f"line {n}: not key=value: {line!r}"
        key, value = line.split("=", 1)
        current.append((key.strip(), value.strip()))
    return sections


def seconds(span: str) -> float:
    """A systemd time span ("5s", "2min 3s", "500ms", "10") in seconds."""
    units = {"ms": 1e-3, "s": 1, "sec": 1, "min": 60, "m": 60, "h": 3600}
    total = 0.0
    for number, unit in re.findall(r"([\d.]+)\s*([a-z]*)", span):
        total += float(number) * units[unit or "s"]
    return total


@pytest.fixture(scope="module")
def unit() -> dict[str, list[tuple[str, str]]]:
    return parse_unit(UNIT.read_text())


def one(unit, section: str, key: str) -> str:
    values = [v for k, v in unit[section] if k == key]
    assert len(values) == 1, f"[{section}] {key}= set {len(values)} times: {values}"
    return values[0]


def every(unit, section: str, key: str) -> list[str]:
    return [v for k, v in unit[section] if k == key]


REQUIRED = {
    "Type": "notify", "NotifyAccess": "main", "Restart": "on-failure",
    "ExecStart": f"{INSTALLED_EXEC} run --config /etc/tactiled/tactiled.toml",
    "KillSignal": "SIGTERM", "KillMode": "mixed",
    "DynamicUser": "yes", "SupplementaryGroups": "dialout",
    "ProtectSystem": "strict", "ProtectHome": "yes", "PrivateTmp": "yes",
    "NoNewPrivileges": "yes", "ProtectKernelTunables": "yes", "ProtectKernelModules": "yes",
    "ProtectControlGroups": "yes", "RestrictNamespaces": "yes", "LockPersonality": "yes",
    "RestrictSUIDSGID": "yes", "CapabilityBoundingSet": "", "SystemCallArchitectures": "native",
    "DevicePolicy": "closed", "SystemCallFilter": "@system-service",
    "StateDirectory": "tactiled", "CacheDirectory": "tactiled", "RuntimeDirectory": "tactiled",
    "ConfigurationDirectory": "tactiled",
}


@pytest.mark.parametrize("key", sorted(REQUIRED))
def test_required_directive(unit, key):
    assert one(unit, "Service", key) == REQUIRED[key]


def test_timeouts_and_watchdog(unit):
    watchdog = seconds(one(unit, "Service", "WatchdogSec"))
    assert 2 <= watchdog <= 30  # pings every WatchdogSec/2; long enough for a busy loop
    assert 1 <= seconds(one(unit, "Service", "RestartSec")) <= 30
    # The daemon stops within 5 s (tested in test_deploy_run_notify.py); leave a margin.
    assert seconds(one(unit, "Service", "TimeoutStopSec")) == 10
    # Start-up waits for warm fit workers: fit.startup_timeout must fit in TimeoutStartSec.
    from tactiled.settings import FitSettings
    assert seconds(one(unit, "Service", "TimeoutStartSec")) > FitSettings().startup_timeout


def test_serial_devices_only(unit):
    assert sorted(every(unit, "Service", "DeviceAllow")) == ["char-ttyACM rw", "char-ttyUSB rw"]
    assert not every(unit, "Service", "PrivateDevices")  # would hide the serial ports
    # The device groups exist only once their drivers are loaded; the unit loads them first.
    for module in ("cdc_acm", "usbserial"):
        for key in ("Wants", "After"):
            assert f"modprobe@{module}.service" in " ".join(every(unit, "Unit", key))


def test_network_families(unit):
    assert one(unit, "Service", "RestrictAddressFamilies").split() == ["AF_UNIX", "AF_INET",
                                                                       "AF_INET6"]


def test_memory_deny_write_execute(unit):
    """Nothing is compiled at run time (the core is built by pip install): the unit denies
    writable-executable memory (test_the_daemon_runs_under_memory_deny_write_execute)."""
    assert one(unit, "Service", "MemoryDenyWriteExecute") == "yes"
    assert "NUMBA_CACHE_DIR" not in UNIT.read_text()


def test_install_section(unit):
    assert one(unit, "Install", "WantedBy") == "multi-user.target"


def test_consistent_with_example_config(unit):
    """The example config names the same command, keeps recordings in StateDirectory= and
    listens on loopback by default."""
    import tomllib
    text = CONFIG.read_text()
    assert "tactiled run --config /etc/tactiled/tactiled.toml" in text
    assert f"/var/lib/{one(unit, 'Service', 'StateDirectory')}/{{sensor}}.tact" in text
    assert tomllib.loads(text)["server"]["host"] == "127.0.0.1"


# -- systemd-analyze --------------------------------------------------------------------------

def runnable_copy(tmp_path: Path, text: str | None = None) -> Path:
    """The unit with ExecStart= pointing at an executable that exists here (verify insists);
    nothing else changed.  In a directory of its own: verify loads every unit beside it."""
    exe = Path(sys.executable).with_name("tactiled")
    exe = exe if exe.exists() else Path("/bin/true")
    text = (text or UNIT.read_text()).replace(f"ExecStart={INSTALLED_EXEC} ", f"ExecStart={exe} ")
    assert f"ExecStart={exe} run" in text
    (tmp_path / "units").mkdir()
    path = tmp_path / "units" / "tactiled.service"
    path.write_text(text)
    return path


def analyze(*args: str) -> subprocess.CompletedProcess:
    if SYSTEMD_ANALYZE is None:
        pytest.skip("systemd-analyze is not installed on this machine (package systemd): the "
                    "unit cannot be verified here")
    return subprocess.run([SYSTEMD_ANALYZE, *args], capture_output=True, text=True, timeout=60)


def test_systemd_analyze_verify_is_clean(tmp_path):
    """No output at all.  This runs without systemd as PID 1 (a container): verify then loads
    the unit and its dependencies (network.target, modprobe@.service) from the usual unit
    directories with a private manager and checks every directive offline -- it printed
    nothing here with systemd 252."""
    result = analyze("verify", str(runnable_copy(tmp_path)))
    assert (result.returncode, result.stdout, result.stderr) == (0, "", "")


def test_systemd_analyze_verify_would_catch_mistakes(tmp_path):
    """The check above means something here: the same verify reports a typo'd key and a bad
    device right (it exits 0 for these, so the test must read stderr)."""
    text = UNIT.read_text().replace("ProtectSystem=strict", "ProtectSytem=strict").replace(
        "DeviceAllow=char-ttyUSB rw", "DeviceAllow=char-ttyUSB rx")
    result = analyze("verify", str(runnable_copy(tmp_path, text)))
    assert "Unknown key 'ProtectSytem'" in result.stderr
    assert "Invalid device rights 'rx'" in result.stderr


def test_systemd_analyze_verify_needs_the_executable(tmp_path):
    """Why the copy: verify refuses the unit as shipped where /opt/tactiled is not installed."""
    if Path(INSTALLED_EXEC).exists():
        pytest.skip(f"{INSTALLED_EXEC} is installed on this machine")
    (tmp_path / "units").mkdir()
    path = tmp_path / "units" / "tactiled.service"
    shutil.copy(UNIT, path)
    result = analyze("verify", str(path))
    assert result.returncode != 0 and f"Command {INSTALLED_EXEC} is not executable" in result.stderr


def test_systemd_analyze_security_exposure(tmp_path):
    result = analyze("security", "--offline=yes", "--no-pager", str(runnable_copy(tmp_path)))
    assert result.returncode == 0, result.stderr
    m = re.search(r"Overall exposure level for tactiled\.service: ([\d.]+)", result.stdout)
    assert m, result.stdout[-500:]
    assert float(m.group(1)) <= MAX_EXPOSURE, result.stdout


# -- MemoryDenyWriteExecute ---------------------------------------------------------------------

PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN = 65, 1  # Linux >= 6.3


def test_the_daemon_runs_under_memory_deny_write_execute(tmp_path):
    """Under the kernel's memory-deny-write-execute (what MemoryDenyWriteExecute=yes imposes,
    inherited across exec and by the fit workers) the daemon starts on the simulated finger
    and serves a fitted estimate: nothing in it needs memory made executable at run time."""
    import json
    import socket
    import time
    import urllib.request

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    tactiled = str(Path(sys.executable).with_name("tactiled"))
    launcher = textwrap.dedent(f"""
        import ctypes, os, sys
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl({PR_SET_MDWE}, {PR_MDWE_REFUSE_EXEC_GAIN}, 0, 0, 0) != 0:
            sys.exit(3)
        os.execv({tactiled!r}, [{tactiled!r}, "run", "--port", "{port}"])
    """)
    log = (tmp_path / "run.log").open("w")
    proc = subprocess.Popen([sys.executable, "-c", launcher], stdout=log, stderr=subprocess.STDOUT,
                            cwd=tmp_path)
    fitted = None
    try:
        deadline = time.monotonic() + 120.0
        while fitted is None and time.monotonic() < deadline and proc.poll() is None:
            try:
                with urllib.request.urlopen(
                        f"http://127.0.0.1:{port}/v1/sensors/finger0/estimate", timeout=2) as r:
                    fitted = json.load(r).get("fitted_seq")
            except OSError:
                pass
            time.sleep(0.1)  # polling interval, not synchronisation: the loop waits on the answer
    finally:
        if proc.poll() is None:
            proc.send_signal(2)
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()
    if proc.returncode == 3:
        pytest.skip("this kernel has no PR_SET_MDWE (Linux < 6.3): cannot impose "
                    "memory-deny-write-execute")
    assert fitted is not None, (tmp_path / "run.log").read_text()[-2000:]


# -- udev rule ---------------------------------------------------------------------------------

_TOKEN = re.compile(r'\s*([A-Z_]+(?:\{[^}]+\})?)\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*(?:,|$)')
_MATCH_KEYS = {"SUBSYSTEM", "KERNEL", "KERNELS", "ATTRS", "ENV"}
_ASSIGN_KEYS = {"SYMLINK", "GROUP", "MODE", "ENV", "TAG", "OWNER"}


def parse_rules(text: str) -> list[list[tuple[str, str, str]]]:
    """Each rule line as [(key, operator, value)]; the whole line must be consumed."""
    rules = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tokens, pos = [], 0
        while pos < len(line):
            m = _TOKEN.match(line, pos)
            assert m, f"99-tactiled.rules:{n}: cannot parse at {line[pos:pos + 40]!r}"
            tokens.append(m.groups())
            pos = m.end()
        rules.append(tokens)
    return rules


def test_udev_rules(unit):
    rules = parse_rules(RULES.read_text())
    assert rules
    symlinks = []
    for tokens in rules:
        for key, op, _value in tokens:
            base = key.split("{")[0]
            assert base in (_MATCH_KEYS if op in ("==", "!=") else _ASSIGN_KEYS), (key, op)
        d = {(k, op): v for k, op, v in tokens}
        assert d[("SUBSYSTEM", "==")] == "tty"
        assert re.fullmatch(r"[0-9a-f]{4}", d[("ATTRS{idVendor}", "==")])
        assert re.fullmatch(r"[0-9a-f]{4}", d[("ATTRS{idProduct}", "==")])
        assert d[("ATTRS{serial}", "==")]
        assert d[("GROUP", "=")] == one(unit, "Service", "SupplementaryGroups")
        assert d[("MODE", "=")] == "0660"
        assert d[("ENV{ID_MM_DEVICE_IGNORE}", "=")] == "1"
        symlinks.append(d[("SYMLINK", "+=")])
    assert all(re.fullmatch(r"tactile/[A-Za-z0-9_.-]+", s) for s in symlinks)
    assert len(set(symlinks)) == len(symlinks)
    assert "udevadm info -a -n /dev/ttyACM0" in RULES.read_text()


def test_rules_parser_rejects_broken_lines():
    with pytest.raises(AssertionError):
        parse_rules('SUBSYSTEM=="tty", ATTRS{idVendor}=="16c0" SYMLINK+="tactile/x"')


# -- docs ------------------------------------------------------------------------------------

def test_docs_name_the_install_steps():
    text = DOCS.read_text()
    for step in ("python3 -m venv /opt/tactiled/.venv", "/etc/systemd/system/tactiled.service",
                 "/etc/udev/rules.d/99-tactiled.rules", "systemctl daemon-reload",
                 "udevadm control --reload", "systemctl enable --now tactiled",
                 "systemctl status tactiled", "journalctl -u tactiled"):
        assert step in text, step
