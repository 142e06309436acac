"""docker-compose.yml and deploy/k8s/ik.yaml say what the failover test runs: the
shipped HAProxy file, IK_REDIS_URL, /readyz for readiness, /healthz for liveness, and
only settings the service has (a misspelt IK_ variable stops the service, or is ignored
with a warning: either way a deployment that names one is broken). No container engine
runs here: these files are read, not run (tests/test_deploy_lint.py puts them through
kubernetes-validate, hadolint and dclint)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import yaml  # PyYAML, installed with schemathesis (the test extra)

from service.config import Settings

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {f"IK_{name.upper()}" for name in Settings.model_fields}
# The peak RSS of a cold start (the solver compiled in its two compile processes),
# `python -m bench.cold_start --cold-runs 1` (bench/RESULTS.md, "Cold start"): 2475 MB.
COLD_COMPILE_PEAK_MIB = 2475 * 1e6 / 2**20


def _compose() -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    return doc


def _k8s() -> list[dict[str, Any]]:
    return [d for d in yaml.safe_load_all((ROOT / "deploy/k8s/ik.yaml").read_text()) if d]


def test_compose_runs_the_shipped_balancer_config_in_front_of_workers_on_redis() -> None:
    services = _compose()["services"]
    assert (
        "./deploy/haproxy.cfg:/usr/local/etc/haproxy/haproxy.cfg:ro"
        in (services["balancer"]["volumes"])
    )
    worker = services["service"]
    assert worker["environment"]["IK_REDIS_URL"].startswith("redis://redis:")
    assert "/readyz" in " ".join(worker["healthcheck"]["test"])
    assert set(worker["environment"]) <= SETTINGS
    # The balancer's server-template names the compose service and the port it listens on.
    cfg = (ROOT / "deploy/haproxy.cfg").read_text()
    assert "server-template ik 4 service:8000" in cfg
    assert worker["deploy"]["replicas"] == 4


def _k8s_worker_pod() -> dict[str, Any]:
    (deployment,) = [
        d for d in _k8s() if (d["kind"], d["metadata"]["name"]) == ("Deployment", "ik")
    ]
    pod: dict[str, Any] = deployment["spec"]["template"]["spec"]
    return pod


def test_k8s_workers_use_redis_and_the_health_routes() -> None:
    by_kind = {(d["kind"], d["metadata"]["name"]): d for d in _k8s()}
    pod = _k8s_worker_pod()
    (container,) = pod["containers"]
    env = {e["name"]: e["value"] for e in container["env"]}
    assert env["IK_REDIS_URL"].startswith("redis://ik-redis:")
    assert set(env) <= SETTINGS
    assert container["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert container["livenessProbe"]["httpGet"]["path"] == "/healthz"
    assert ("Service", "ik-redis") in by_kind and ("Service", "ik") in by_kind
    ingress = by_kind[("Ingress", "ik")]["metadata"]["annotations"]
    assert "upstream-hash-by" in " ".join(ingress)


def test_the_workers_believe_the_balancer_s_forwarded_for() -> None:
    """HAProxy names the client (``option forwardfor``), in place of any header the
    client sent (tests/live/test_forwarded.py shows why); the workers behind it believe
    that header from a list they can start with, so that per-address limits and logs see
    each client rather than one balancer (and need not be switched off)."""
    cfg = (ROOT / "deploy/haproxy.cfg").read_text()
    assert "\n    option forwardfor\n" in cfg
    frontend = cfg.split("\nfrontend ik\n")[1].split("\n\n")[0]
    assert "\n    http-request del-header X-Forwarded-For\n" in frontend
    (container,) = _k8s_worker_pod()["containers"]
    k8s = {e["name"]: e["value"] for e in container["env"]}
    for env in (_compose()["services"]["service"]["environment"], k8s):
        assert Settings(forwarded_allow_ips=env["IK_FORWARDED_ALLOW_IPS"]).trusted_proxies()
        assert "IK_SESSIONS_PER_ADDRESS_PER_MIN" not in env
        assert "IK_MAX_CONNECTIONS_PER_ADDRESS" not in env


def test_k8s_admits_only_the_ingress_controller_to_the_workers_port() -> None:
    """The workers believe X-Forwarded-For from the private networks, which hold every
    pod, and spare those peers the per-address connection cap: a NetworkPolicy on the
    workers' own labels admits only the ingress controller's namespace, and only to the
    port the Service sends to (a policy whose selector missed the pods would isolate
    nothing; one on another port would shut the ingress out)."""
    by_kind = {(d["kind"], d["metadata"]["name"]): d for d in _k8s()}
    deployment = by_kind[("Deployment", "ik")]
    labels = deployment["spec"]["selector"]["matchLabels"]
    assert labels.items() <= deployment["spec"]["template"]["metadata"]["labels"].items()
    policies = [d for d in _k8s() if d["kind"] == "NetworkPolicy"]
    (policy,) = [p for p in policies if p["spec"]["podSelector"]["matchLabels"] == labels]
    assert policy["spec"]["policyTypes"] == ["Ingress"]
    (rule,) = policy["spec"]["ingress"]
    assert rule["from"] == [
        {"namespaceSelector": {"matchLabels": {"kubernetes.io/metadata.name": "ingress-nginx"}}}
    ]
    (container,) = _k8s_worker_pod()["containers"]
    (served,) = by_kind[("Service", "ik")]["spec"]["ports"]
    (port,) = container["ports"]
    assert served["targetPort"] in (port["name"], port["containerPort"])
    assert [(p["protocol"], p["port"]) for p in rule["ports"]] in (
        [("TCP", port["name"])],
        [("TCP", port["containerPort"])],
    )
    assert policy["metadata"].get("namespace") == deployment["metadata"].get("namespace")


def test_k8s_admits_only_the_workers_to_redis() -> None:
    """Redis holds every session and asks no password: a NetworkPolicy on its pods'
    labels admits the workers' pods only, on the port it listens on."""
    by_kind = {(d["kind"], d["metadata"]["name"]): d for d in _k8s()}
    redis = by_kind[("Deployment", "ik-redis")]
    labels = redis["spec"]["selector"]["matchLabels"]
    assert labels.items() <= redis["spec"]["template"]["metadata"]["labels"].items()
    policies = [d for d in _k8s() if d["kind"] == "NetworkPolicy"]
    (policy,) = [p for p in policies if p["spec"]["podSelector"]["matchLabels"] == labels]
    assert policy["spec"]["policyTypes"] == ["Ingress"]
    (rule,) = policy["spec"]["ingress"]
    workers = by_kind[("Deployment", "ik")]["spec"]["template"]["metadata"]["labels"]
    (source,) = rule["from"]
    assert source["podSelector"]["matchLabels"].items() <= workers.items()
    assert set(source) == {"podSelector"}  # the workers' own namespace, no other
    (container,) = redis["spec"]["template"]["spec"]["containers"]
    (port,) = container["ports"]
    assert rule["ports"] == [{"protocol": "TCP", "port": port["containerPort"]}]


def test_k8s_memory_limit_lets_a_cold_start_compile() -> None:
    """A pod that must compile the solver (an image without its cache) is not killed
    for memory on every start: a crash loop no log line explains."""
    (container,) = _k8s_worker_pod()["containers"]
    limit = container["resources"]["limits"]["memory"]
    mib = {"Gi": 1024.0, "Mi": 1.0}[limit[-2:]] * float(limit[:-2])
    assert mib >= 1.1 * COLD_COMPILE_PEAK_MIB, limit


def test_k8s_runs_the_image_under_the_project_s_version() -> None:
    """Not ``:latest`` (Kubernetes pulls that on every start, from Docker Hub, where
    there is no such image): the project's version, as the comment's ``docker build
    -t`` tags it, pulled only if the node lacks it."""
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    (container,) = _k8s_worker_pod()["containers"]
    assert container["image"] == f"ik-service:{version}"
    assert container["imagePullPolicy"] == "IfNotPresent"


def test_k8s_service_links_cannot_set_an_ik_setting() -> None:
    """Service ``ik`` would inject IK_PORT=tcp://<ip>:80 (and ik-redis IK_REDIS_PORT,
    ...) into every pod started after it: IK_PORT is a setting, and such a value stops
    the start (exit 1), a crash loop that only appears on a real cluster."""
    services = {d["metadata"]["name"] for d in _k8s() if d["kind"] == "Service"}
    injected = {f"{name.upper().replace('-', '_')}_PORT" for name in services}
    if injected & SETTINGS or any(n.upper().startswith("IK") for n in services):
        assert _k8s_worker_pod()["enableServiceLinks"] is False


def test_the_k8s_redis_is_replaced_not_rolled() -> None:
    # An operator trial: the default RollingUpdate starts a second, empty Redis beside
    # the old one while the Service routes to both.
    (redis,) = [
        d for d in _k8s() if (d["kind"], d["metadata"]["name"]) == ("Deployment", "ik-redis")
    ]
    assert redis["spec"]["replicas"] == 1
    assert redis["spec"]["strategy"] == {"type": "Recreate"}
