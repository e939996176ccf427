"""coartic batch on a cluster started apart from the client, as on a real one.

``dask scheduler`` and ``dask worker`` run as their own processes, in a directory that is not the
client's, on loopback only; the client runs ``coartic batch`` with the batch spec given relative to
its own directory (the README's example). Once over plain TCP, once over Dask's TLS with
certificates made here by the ``openssl`` command. Every process is bounded in time and stopped.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from typer.testing import CliRunner

from coartic.batch import load_batch_spec
from coartic.batch.layout import unit_dir
from coartic.batch.run import ClusterError, Tls, cluster_security, run_batch
from coartic.batch.tasks import UnitKey
from coartic.cli import app
from coartic.table import ParameterTable

from conftest import without_overview

pytestmark = pytest.mark.slow

# Two free parameters: these tests are about the units running on a cluster and giving serial's tables
# byte for byte, not about the fit; the five of a full fit made the serial run and each cluster's 36
# CPU-s instead of ~1.3 (bench/results/test_suite_cpu_rest2.txt).
FIT_SPEC = """name = "tiny"
[corpus]
manifest = "unused.csv"
[model]
channels = ["JO"]
[parameters]
free = ["target", "alpha"]
[staging]
enabled = false
[fit]
starts = 1  # (the remote workers do not see conftest's single-start default)
"""
BATCH_SPEC = """name = "two speakers"
fit = "fit.toml"
[corpus]
manifest = "corpus/manifest.csv"
group_by = ["speaker"]
"""
START_TIMEOUT_S = 60.0
UNITS = (UnitKey("s01", "JO"), UnitKey("s02", "JO"), UnitKey(None, "JO"))


@pytest.fixture(scope="module")
def client_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("client")
    with without_overview() as gen:  # the speakers' overview figures: 2 CPU-s each, never looked at here
        gen.generate(root / "corpus", quick=True, progress=False, consonants=["p"], speakers=2)
    (root / "fit.toml").write_text(FIT_SPEC)
    (root / "batch.toml").write_text(BATCH_SPEC)
    return root


@pytest.fixture(scope="module")
def serial(client_dir: Path) -> Path:
    out = client_dir / "serial"
    # no report: the clusters' units are compared with its units' tables, nothing else
    assert run_batch(load_batch_spec(client_dir / "batch.toml"), out, serial=True, quiet=True, report=False).complete
    return out


def make_certificates(where: Path) -> dict[str, Path]:
    """A CA and one certificate signed by it for 127.0.0.1 (scheduler, worker and client share it)."""
    where.mkdir()
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=where, check=True, capture_output=True, timeout=30)

    openssl("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "1", "-subj", "/CN=coartic test CA")
    openssl("req", *ec, "-keyout", "node.key", "-out", "node.csr", "-subj", "/CN=127.0.0.1")
    (where / "san.cnf").write_text("subjectAltName=IP:127.0.0.1\n")
    openssl("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", "node.pem", "-days", "1", "-extfile", "san.cnf")
    return {"ca": where / "ca.pem", "cert": where / "node.pem", "key": where / "node.key"}


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in reversed(procs):  # workers first, then the scheduler
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)


@contextmanager
def dask_cluster(where: Path, certs: dict[str, Path] | None = None) -> Iterator[str]:
    """A scheduler and one worker started with Dask's own command in ``where``; yields the address."""
    where.mkdir()
    tls = [] if certs is None else ["--tls-ca-file", str(certs["ca"]), "--tls-cert", str(certs["cert"]),
                                    "--tls-key", str(certs["key"])]
    env = {**os.environ, "RAYON_NUM_THREADS": "1"}
    dask = [sys.executable, "-m", "dask"]
    procs: list[subprocess.Popen[bytes]] = []
    try:
        procs.append(subprocess.Popen(
            [*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file",
             "scheduler.json", *(["--protocol", "tls"] if certs else []), *tls],
            cwd=where, env=env, stdout=subprocess.DEVNULL, stderr=open(where / "scheduler.log", "wb")))
        deadline = time.monotonic() + START_TIMEOUT_S
        while not (where / "scheduler.json").is_file():
            assert procs[0].poll() is None, (where / "scheduler.log").read_text()
            assert time.monotonic() < deadline, "the scheduler did not start"
            time.sleep(0.2)
        time.sleep(0.2)  # the file is written whole, but give the writer its close
        address = json.loads((where / "scheduler.json").read_text())["address"]
        assert address.startswith("tls://127.0.0.1:" if certs else "tcp://127.0.0.1:")
        procs.append(subprocess.Popen(
            [*dask, "worker", address, "--host", "127.0.0.1", "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
             "--local-directory", str(where / "scratch"), *tls],
            cwd=where, env=env, stdout=subprocess.DEVNULL, stderr=open(where / "worker.log", "wb")))
        from distributed import Client

        security = cluster_security(address, Tls(certs["ca"], certs["cert"], certs["key"]) if certs else None)
        with Client(address, timeout="30s", security=security) as c:
            c.wait_for_workers(1, timeout=START_TIMEOUT_S)
        yield address
    finally:
        _stop(procs)


def run_cli_in(directory: Path, *args: str) -> tuple[int, str]:
    here = os.getcwd()
    os.chdir(directory)
    try:
        r = CliRunner().invoke(app, ["batch", *args])
    finally:
        os.chdir(here)
    return r.exit_code, r.output


def assert_same_units(out: Path, serial: Path) -> None:
    for key in UNITS:
        got, ref = unit_dir(out, key), unit_dir(serial, key)
        assert (got / "table.csv").read_bytes() == (ref / "table.csv").read_bytes(), key.label
        assert json.loads((got / "unit.json").read_text())["pid"] != os.getpid()  # ran on the worker


@pytest.fixture(scope="module", params=["tcp", "tls"])
def cluster(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
            ) -> Iterator[tuple[str, dict[str, Path] | None]]:
    """The address of a scheduler and worker over ``tcp`` or ``tls`` (and the TLS certificates). One
    module-scoped fixture with the protocol as its parameter: pytest runs every test of the TCP cluster,
    stops it, then starts the TLS one, so that the two clusters' processes (idle ones poll and profile
    themselves) never run side by side."""
    where = tmp_path_factory.mktemp(request.param)
    certs = make_certificates(where / "certs") if request.param == "tls" else None
    with dask_cluster(where / "cluster", certs) as address:
        yield address, certs


def test_readme_batch_runs_on_a_scheduler_and_worker_started_elsewhere(
        client_dir: Path, serial: Path, cluster: tuple[str, dict[str, Path] | None]) -> None:
    address, certs = cluster
    protocol = "tcp" if certs is None else "tls"
    tls = [] if certs is None else ["--tls-ca-file", str(certs["ca"]), "--tls-cert", str(certs["cert"]),
                                    "--tls-key", str(certs["key"])]
    code, output = run_cli_in(client_dir, "batch.toml", "--out", f"out-{protocol}", "--scheduler", address, *tls)
    assert code == 0, output
    assert_same_units(client_dir / f"out-{protocol}", serial)
    if certs is not None:  # the scheduler takes no unencrypted client
        with pytest.raises(ClusterError, match="needs the CA certificate"):
            run_batch(load_batch_spec(client_dir / "batch.toml"), client_dir / "out-none", scheduler=address,
                      quiet=True)
        assert not (client_dir / "out-none").exists()  # refused before any output


@pytest.mark.parametrize("cluster", ["tcp"], indirect=True)
def test_a_worker_without_the_recordings_names_the_path_and_the_host(
        client_dir: Path, tmp_path: Path, cluster: tuple[str, dict[str, Path] | None]) -> None:
    elsewhere = tmp_path / "moved"
    shutil.copytree(client_dir, elsewhere, ignore=shutil.ignore_patterns("serial", "out-*"))
    spec = load_batch_spec(elsewhere / "batch.toml")
    assert spec.path.is_absolute() and all(g.spec.corpus.manifest.is_absolute() for g in spec.groups)  # type: ignore[union-attr]
    shutil.rmtree(elsewhere / "corpus")  # read by the client, then gone before the workers look
    outcome = run_batch(spec, tmp_path / "out", scheduler=cluster[0], quiet=True)
    assert len(outcome.failed) == 3
    why = outcome.failed["s01 JO"]
    assert str(elsewhere / "corpus" / "manifest.csv") in why and "not readable on the worker" in why
    assert "build/session" not in why


def test_tls_certificates_come_from_options_or_the_dask_configuration(tmp_path: Path) -> None:
    import dask.config

    certs = make_certificates(tmp_path / "certs")
    sec = cluster_security("tls://127.0.0.1:1", Tls(certs["ca"], certs["cert"], certs["key"]))
    assert sec.require_encryption and sec.tls_ca_file == str(certs["ca"]) and sec.tls_client_cert == str(certs["cert"])
    with dask.config.set({"distributed.comm.tls.ca-file": str(certs["ca"]),
                          "distributed.comm.tls.client.cert": str(certs["cert"]),
                          "distributed.comm.tls.client.key": str(certs["key"])}):
        sec = cluster_security("tls://127.0.0.1:1", None)
    assert sec.tls_client_key == str(certs["key"]) and sec.tls_ca_file == str(certs["ca"])
    with pytest.raises(ClusterError, match="--tls-cert"):
        cluster_security("tls://127.0.0.1:1", Tls(ca_file=certs["ca"]))
    with pytest.raises(ClusterError, match="does not exist"):
        cluster_security("tls://127.0.0.1:1", Tls(tmp_path / "nope.pem", certs["cert"]))
    with pytest.raises(ClusterError, match="not tls://"):
        cluster_security("tcp://127.0.0.1:1", Tls(certs["ca"], certs["cert"]))
    assert cluster_security("tcp://127.0.0.1:1", None) is None
