"""Settings from IK_* environment variables."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
from pydantic import ValidationError

from service.config import (
    Settings,
    misspelt_variables,
    service_link_hint,
    settings_errors,
    unknown_variables,
)

from .helpers import python_m_service


@pytest.fixture(autouse=True)
def clean_environ(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    for key in list(os.environ):
        if key.startswith("IK_"):
            monkeypatch.delenv(key)
    yield


def test_defaults() -> None:
    s = Settings()
    assert (s.host, s.port) == ("127.0.0.1", 8000)
    assert s.session_ttl_s == 300.0 and s.max_sessions == 1000


def test_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("IK_PORT", "9001")
    monkeypatch.setenv("IK_MAX_SESSIONS", "7")
    monkeypatch.setenv("IK_DEFAULT_TIME_BUDGET_US", "250.5")
    monkeypatch.setenv("IK_INLINE_BUDGET_US", "0")
    s = Settings()
    assert s.port == 9001 and s.max_sessions == 7
    assert s.default_time_budget_us == 250.5 and s.inline_budget_us == 0.0


def test_a_variable_set_to_nothing_keeps_its_default(monkeypatch: pytest.MonkeyPatch) -> None:
    # docker compose's "IK_X=" for unset (an operator trial: refused, exit 1).
    monkeypatch.setenv("IK_DEFAULT_MAX_RESTARTS", "")
    monkeypatch.setenv("IK_PORT", "")
    s = Settings()
    default = Settings.model_fields["default_max_restarts"].default
    assert (s.default_max_restarts, s.port) == (default, 8000)
    assert misspelt_variables({"IK_PORT": "", "IK_DEFAULT_MAX_RESTARTS": ""}) == {}


def test_an_empty_host_is_refused_not_taken_as_loopback() -> None:
    # A review: an empty IK_HOST bound every interface before empty variables kept their
    # defaults; 127.0.0.1 would hide a container (the image sets 0.0.0.0) from its
    # network. The start says so instead.
    problems = misspelt_variables({"IK_HOST": ""})
    assert problems["IK_HOST"].startswith("IK_HOST is empty: give the address to bind")


def test_bad_values_are_rejected(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("IK_MAX_SESSIONS", "0")
    with pytest.raises(ValidationError):
        Settings()


def test_a_bad_value_is_said_in_the_environment_s_names(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("IK_MAX_SESSIONS", "abc")
    with pytest.raises(ValidationError) as err:
        Settings()
    text = settings_errors(err.value)
    assert "IK_MAX_SESSIONS: " in text and "'abc'" in text and "max_sessions" not in text


@pytest.mark.parametrize(
    ("url", "says"),
    [
        ("http://:hunter2@cache:6379/0", "must start with redis://, rediss:// or unix://"),
        ("redis://:hunter2@cache:99999/0", "not a URL with a port redis-py can read"),
        # An unencoded / in the password: urlsplit takes what follows the : for a port.
        ("redis://:hunter2/x@cache:6379/0", "percent-encode a password"),
        # ... and after an @ in it: the rest of the password is read as the path.
        ("redis://:hunter2@x/y@cache:6379/0", "percent-encode a password that holds /"),
        # redis-py would read these paths as database 0 without a word.
        ("redis://:hunter2@cache:6379/sessions", "the path is the database number"),
        ("redis://:hunter2@cache:6379/\u00b2", "the path is the database number"),
        ("redis://:hunter2@cache:6379/0?socket_timeout=7", "use IK_REDIS_TIMEOUT_S"),
        ("redis://:hunter2@cache:6379/0?foo=1", "?foo is not a connection option"),
        ("redis://:hunter2@cache:6379?db=abc", "?db has a value redis-py cannot read"),
        ("unix://", "unix:// needs the socket's path"),
    ],
)
def test_a_redis_url_the_service_cannot_use_is_refused_at_start_without_its_password(
    monkeypatch: pytest.MonkeyPatch, url: str, says: str
) -> None:
    monkeypatch.setenv("IK_REDIS_URL", url)
    with pytest.raises(ValidationError) as err:
        Settings()
    text = settings_errors(err.value)
    assert text.startswith("invalid configuration:\n  IK_REDIS_URL: "), text
    assert says in text
    # Neither the message nor the exception itself (create_app under uvicorn shows it).
    for shown in (text, str(err.value)):
        assert "hunter2" not in shown and "cache" not in shown, shown


@pytest.mark.parametrize(
    "url",
    [
        "redis://127.0.0.1:6379/0",
        "redis://localhost:6379/",
        "redis://cache/0/",
        "redis://cache/%31",
        "redis://cache/sessions?db=2",
        "redis://[::1]:6379/0",
        "rediss://user:p%40ss@cache:6380/3?ssl_cert_reqs=none",
        "redis://cache",
        "unix:///run/r.sock?db=1",
    ],
)
def test_redis_urls_redis_py_opens_are_taken(monkeypatch: pytest.MonkeyPatch, url: str) -> None:
    monkeypatch.setenv("IK_REDIS_URL", url)
    assert Settings().redis_url.get_secret_value() == url


def test_log_level_in_any_case(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("IK_LOG_LEVEL", "WARNING")
    assert Settings().log_level == "warning"


def test_unknown_ik_variables_are_named_with_the_closest_setting() -> None:
    env = {
        "IK_REDIS_UR": "redis://x",  # a typo of a setting that is not set: refused
        "IK_PORT": "1",
        "IK_LOGLEVEL": "debug",  # a typo too, and IK_LOG_LEVEL is set: a warning
        "IK_LOG_LEVEL": "info",
        "PATH": "/bin",
        "IK_LB_BIND": "127.0.0.1:8080",  # HAProxy's (docs/operations.md): a warning
    }
    assert list(misspelt_variables(env).values()) == [
        "IK_REDIS_UR is not a setting of this service: did you mean IK_REDIS_URL?"
    ]
    warnings = unknown_variables(env)
    assert len(warnings) == 2, warnings
    bind, typo = warnings
    assert bind == "IK_LB_BIND is not a setting of this service and is ignored"
    assert typo.startswith("IK_LOGLEVEL is not a setting") and "IK_LOG_LEVEL?" in typo


def test_redis_variables_other_than_the_url_are_refused_without_it() -> None:
    """IK_REDIS_HOST and the like mean Redis was wanted: without IK_REDIS_URL they stop
    the start; beside it they are only warned of."""
    env = {"IK_REDIS_HOST": "cache", "IK_REDIS_PASSWORD": "x"}
    refused = misspelt_variables(env)
    assert sorted(refused) == ["IK_REDIS_HOST", "IK_REDIS_PASSWORD"]
    assert "IK_REDIS_URL alone" in refused["IK_REDIS_HOST"]
    env["IK_REDIS_URL"] = "redis://cache:6379/0"
    assert misspelt_variables(env) == {}
    assert len(unknown_variables(env)) == 2


def test_a_misspelt_setting_stops_the_start_with_its_name() -> None:
    """``python -m service`` with IK_REDIS_UR: exit 1 before binding, saying what was
    meant (a worker without its Redis would pass /readyz and lose sessions)."""
    done = python_m_service(IK_REDIS_UR="redis://127.0.0.1:1/0", IK_PORT="1")
    assert done.returncode == 1, done
    assert done.stderr.strip().endswith(
        "invalid configuration:\n  IK_REDIS_UR is not a setting of this service: "
        "did you mean IK_REDIS_URL?"
    ), done.stderr


def test_python_m_service_takes_no_arguments_and_help_lists_the_variables() -> None:
    """An operator trial: ``--help`` started the server and ``--port 18012`` was
    silently ignored (it bound IK_PORT)."""
    # IK_PORT=1: were the server to start, it could not bind.
    helped = python_m_service("--help", IK_PORT="1")
    assert helped.returncode == 0, helped
    assert helped.stdout.startswith("usage: [IK_VARIABLE=value ...] python -m service")
    for name in Settings.model_fields:
        assert f"  IK_{name.upper()} (default " in helped.stdout
    refused = python_m_service("--port", "18012", IK_PORT="1")
    assert refused.returncode == 1, refused
    assert "takes no arguments (got '--port 18012')" in refused.stderr
    assert "IK_PORT=8001 python -m service" in refused.stderr


def test_frozen() -> None:
    with pytest.raises(ValidationError):
        Settings().port = 1  # type: ignore[misc]


def test_restarts_default_to_the_solvers_own(monkeypatch: pytest.MonkeyPatch) -> None:
    """Unset, IK_DEFAULT_MAX_RESTARTS leaves each kind of solve its solver default
    (IKOptions for one-shot solves, STREAM_DEFAULTS for sessions); set, it sets both."""
    from service import convert
    from solver.ik import STREAM_DEFAULTS, IKOptions

    s = Settings()
    assert convert.oneshot_defaults(s).max_restarts == IKOptions().max_restarts == 126
    assert convert.session_defaults(s).max_restarts == STREAM_DEFAULTS.max_restarts == 50
    monkeypatch.setenv("IK_DEFAULT_MAX_RESTARTS", "7")
    s = Settings()
    assert convert.oneshot_defaults(s).max_restarts == 7
    assert convert.session_defaults(s).max_restarts == 7


def test_service_links_are_named_as_the_cause_of_a_refused_start() -> None:
    """A pod started after a Service named ik gets IK_PORT=tcp://ip:80 (and ik-redis
    IK_REDIS_PORT=...): the start stops naming the variable, and says where it came
    from and what to set."""
    done = python_m_service(
        KUBERNETES_SERVICE_HOST="10.96.0.1",
        IK_PORT="tcp://10.96.0.12:80",
        IK_SERVICE_HOST="10.96.0.12",
    )
    assert done.returncode == 1, done
    assert "IK_PORT: " in done.stderr, done.stderr
    assert "IK_PORT come from Kubernetes' service links" in done.stderr
    assert "enableServiceLinks: false" in done.stderr
    # Without Redis wanted by URL, the linked IK_REDIS_* stop it too, with the hint.
    assert misspelt_variables({"IK_REDIS_PORT": "tcp://10.96.0.13:6379", "IK_REDIS_URL": ""})
    assert service_link_hint({"IK_PORT": "8000"}) is None  # not on Kubernetes


@pytest.mark.parametrize("host", ["256.1.1.1", "1.2.3.4.5", "a..b", "x" * 64, "::g"])
def test_a_host_that_is_neither_an_address_nor_a_name_is_refused_at_start(
    monkeypatch: pytest.MonkeyPatch, host: str
) -> None:
    """uvicorn would fail at bind with "Name or service not known", naming no variable."""
    monkeypatch.setenv("IK_HOST", host)
    with pytest.raises(ValidationError) as err:
        Settings()
    assert settings_errors(err.value).startswith("invalid configuration:\n  IK_HOST: ")


@pytest.mark.parametrize(
    "host",
    [
        "127.0.0.1",
        "0.0.0.0",
        "::",
        "::1",
        "fe80::1%eth0",
        "127.1",
        "localhost",
        "ik.default.svc.cluster.local",
        "proj_service_1",  # Docker Compose's container names
    ],
)
def test_addresses_and_host_names_are_taken(monkeypatch: pytest.MonkeyPatch, host: str) -> None:
    monkeypatch.setenv("IK_HOST", host)
    assert Settings().host == host


@pytest.mark.parametrize(
    ("value", "said"),
    [
        ("*", "'*' would believe the address a client writes itself"),
        ("10.0.0.1/8", "'10.0.0.1/8' is not an IP address or network"),
        ("10.0.0.5, proxy.local", "'proxy.local' is not an IP address or network"),
    ],
)
def test_forwarded_allow_ips_that_uvicorn_would_misread_stop_the_start(
    monkeypatch: pytest.MonkeyPatch, value: str, said: str
) -> None:
    """uvicorn takes an entry it cannot read as a literal that never matches, and ``*``
    as the header's first entry, which the client writes."""
    monkeypatch.setenv("IK_FORWARDED_ALLOW_IPS", value)
    with pytest.raises(ValidationError) as err:
        Settings()
    text = settings_errors(err.value)
    assert text.startswith("invalid configuration:\n  IK_FORWARDED_ALLOW_IPS: ") and said in text


def test_forwarded_allow_ips_lists_addresses_and_networks(monkeypatch: pytest.MonkeyPatch) -> None:
    assert not Settings().trusted_proxies()  # default: no proxy header believed
    monkeypatch.setenv("IK_FORWARDED_ALLOW_IPS", "10.0.0.5, 10.244.0.0/16,::1")
    proxies = Settings().trusted_proxies()
    assert proxies.as_list() == ["10.0.0.5/32", "10.244.0.0/16", "::1/128"]
    inside = ("10.0.0.5", "10.244.3.7", "::1")
    outside = ("10.0.0.6", "10.245.0.1", "127.0.0.1", "not-an-address", "")
    assert all(a in proxies for a in inside)
    assert not any(a in proxies for a in outside)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("IK_SESSION_TTL_S", "inf"),
        ("IK_REDIS_TIMEOUT_S", "Infinity"),
        ("IK_REDIS_WRITE_BEHIND_MS", "inf"),
        ("IK_HEADER_TIMEOUT_S", "1e400"),
        ("IK_MAX_FRAMES_PER_S", "-inf"),
        ("IK_SWEEP_INTERVAL_S", "nan"),
    ],
)
def test_numbers_that_are_not_finite_are_refused(
    monkeypatch: pytest.MonkeyPatch, name: str, value: str
) -> None:
    """An operator trial: IK_SESSION_TTL_S=inf started and answered every new session
    with a 500 (OverflowError, Redis keys' expiry in ms); inf also unbounded the Redis
    timeout and never wrote behind."""
    monkeypatch.setenv(name, value)
    with pytest.raises(ValidationError) as err:
        Settings()
    assert settings_errors(err.value).startswith(f"invalid configuration:\n  {name}: ")


def test_a_session_ttl_redis_cannot_set_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    # 1e300 s started, and every new session was a 503 saying to check IK_REDIS_URL.
    monkeypatch.setenv("IK_SESSION_TTL_S", "1e300")
    with pytest.raises(ValidationError) as err:
        Settings()
    assert "IK_SESSION_TTL_S: Input should be less than or equal to 31536000" in (
        settings_errors(err.value)
    )
    monkeypatch.setenv("IK_SESSION_TTL_S", "31536000")
    assert Settings().session_ttl_s == 31_536_000
