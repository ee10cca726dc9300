#!/usr/bin/env bash
# A multi-node Ray cluster on one machine: a head node and N worker nodes, each its own raylet.
#
#   cluster/local_cluster.sh start [WORKERS] [CPUS_PER_NODE]   # default 1 worker node, 1 CPU each
#   cluster/local_cluster.sh status
#   cluster/local_cluster.sh stop
#
# Environment: RAY_PORT (6379), DASHBOARD_PORT (8265: the Jobs API), RAY_CLIENT_PORT (10001: ray://; outside Ray's worker ports 10002-19999), RAY (the ray executable,
# default .venv/bin/ray), RAY_TMP (the head's temp dir, default /tmp/ray; worker node i uses RAY_TMP-w<i>),
# PROCTEX_CLUSTER_WAIT (180: seconds `start` waits for the nodes' CPUs and for the job agent).
# `start` returns once every node's CPUs are registered and the Jobs API has run a no-op job (proctex-ready-*), so a
# submission right after it is not refused with "No available agent"; it exits 1 when that takes longer.
# Prints the address to export:
#   export RAY_ADDRESS=http://127.0.0.1:8265   # for `ray job submit` / JobSubmissionClient
#   ray.init(address="127.0.0.1:6379")         # for drivers on this machine (proctex build --ray 127.0.0.1:6379)
set -euo pipefail
cd "$(dirname "$0")/.."
RAY=${RAY:-.venv/bin/ray}
PY=${PY:-$(dirname "$RAY")/python}  # the Python beside that ray, for the readiness check (workflows/jobs.py)
RAY_PORT=${RAY_PORT:-6379}
DASHBOARD_PORT=${DASHBOARD_PORT:-8265}
RAY_TMP=${RAY_TMP:-/tmp/ray}
RAY_CLIENT_PORT=${RAY_CLIENT_PORT:-10001}
export RAY_USAGE_STATS_ENABLED=0
# Tasks and actors at the nodes' own priority, not Ray's default niceness 15 (behind any other work
# on a busy machine they barely ran: workflows/__init__.py); a value you export wins.
export RAY_worker_niceness=${RAY_worker_niceness:-0}
# Not loopback only: Ray 2.60 rewrites --node-ip-address=127.0.0.1 to the machine's routable address
# (only RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 keeps it, and then no worker node may join), so the GCS,
# the raylets, the workers and the agents listen on that address or on every interface; the
# dashboard (the Jobs API) and the Ray Client server listen on 127.0.0.1. What guards the rest is
# Ray's token authentication, on, with a token of this cluster's own: RAY_TMP/auth_token (0600, made
# by `start`), unless you export RAY_AUTH_TOKEN or RAY_AUTH_TOKEN_PATH. A driver, `ray status` and
# the Jobs API need the same variables; `start` prints them.
export RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=1
export RAY_AUTH_MODE=token
if [ -z "${RAY_AUTH_TOKEN:-}" ] && [ -z "${RAY_AUTH_TOKEN_PATH:-}" ]; then
  export RAY_AUTH_TOKEN_PATH="$RAY_TMP/auth_token"
fi

make_token() {
  [ -n "${RAY_AUTH_TOKEN:-}" ] && return
  [ -s "$RAY_AUTH_TOKEN_PATH" ] && return
  mkdir -p "$(dirname "$RAY_AUTH_TOKEN_PATH")"
  (umask 077; "$PY" -c 'import secrets; print(secrets.token_hex(32))' > "$RAY_AUTH_TOKEN_PATH")
}

start() {
  local workers=${1:-1} cpus=${2:-1}
  make_token
  # Two clusters on one machine (another RAY_PORT, DASHBOARD_PORT, RAY_CLIENT_PORT and RAY_TMP) must not
  # share a port: the head's dashboard agent (the Jobs API's agent) takes a free port instead of Ray's
  # fixed 52365, where a second head's agent could not listen and its Jobs API never took a job, and its
  # Ray Client server takes RAY_CLIENT_PORT (Ray binds 10001 with SO_REUSEPORT: two heads would share it).
  "$RAY" start --head --node-ip-address=127.0.0.1 --port="$RAY_PORT" --num-cpus="$cpus" --include-dashboard=true \
    --dashboard-host=127.0.0.1 --dashboard-port="$DASHBOARD_PORT" --dashboard-agent-listen-port=0 \
    --ray-client-server-port="$RAY_CLIENT_PORT" --temp-dir="$RAY_TMP" --disable-usage-stats >/dev/null
  for ((i = 0; i < workers; i++)); do
    # A second raylet on the same host: its own dashboard-agent port (the default 52365 is the head's).
    # Its own temp dir (sessions, logs, spilled objects): nodes share no Ray files, as on separate hosts.
    "$RAY" start --address="127.0.0.1:$RAY_PORT" --node-ip-address=127.0.0.1 --num-cpus="$cpus" --dashboard-agent-listen-port=0 \
      --min-worker-port=0 --max-worker-port=0 --temp-dir="${RAY_TMP}-w$i" --disable-usage-stats >/dev/null
  done
  # Wait until every node has registered its CPUs with the head, then until the head's job agent
  # runs a job (a no-op one, left in its job list): the Jobs API answers "No available agent" before that.
  local want=$((cpus * (workers + 1))) wait_s=${PROCTEX_CLUSTER_WAIT:-180} t0=$SECONDS
  until "$RAY" status --address="127.0.0.1:$RAY_PORT" 2>/dev/null | grep -q "/${want}.0 CPU"; do
    if ((SECONDS - t0 > ${wait_s%.*})); then
      echo "error: the cluster's nodes did not register ${want} CPUs within ${wait_s} s (PROCTEX_CLUSTER_WAIT)" >&2
      exit 1
    fi
    sleep 1
  done
  "$PY" -m workflows.jobs wait "http://127.0.0.1:$DASHBOARD_PORT" --timeout "$wait_s" >/dev/null
  echo "ray cluster: head 127.0.0.1:$RAY_PORT + $workers worker node(s), $cpus CPU(s) each"
  echo "jobs API / dashboard: http://127.0.0.1:$DASHBOARD_PORT"
  echo "clients need: export RAY_AUTH_MODE=token RAY_AUTH_TOKEN_PATH=${RAY_AUTH_TOKEN_PATH:-}"
}

# Stop only this cluster's processes: the Ray processes it started name its temp dir (RAY_TMP) or its
# head's port (RAY_PORT) on their command lines, or hold files under RAY_TMP open; other Ray
# instances on the machine (another temp dir and port) are left alone. With the shared default /tmp/ray, any Ray using that dir stops too:
# give RAY_TMP a dir of its own.
ours() {
  {
    pgrep -f -- "$RAY_TMP|:${RAY_PORT}( |$)" || true
    # Renamed processes (ray::DashboardAgent, ...) name neither, but hold files under RAY_TMP (the
    # head's) or RAY_TMP-wN (a worker node's) open. One find over /proc: an ls per process took ~1 s.
    { find /proc/[0-9]*/fd -maxdepth 1 \( -lname "$RAY_TMP/*" -o -lname "$RAY_TMP-w*" \) 2>/dev/null || true; } | cut -d/ -f3
  } | { grep -vx -e "$$" -e "$PPID" || true; } | sort -u  # not this script, nor its caller (a driver that used the cluster)
}

stop() {
  local pids
  pids=$(ours)
  if [ -n "$pids" ]; then
    kill $pids 2>/dev/null || true
    # 5 s, then SIGKILL: the GCS server, the raylets and the runtime-env agents still drain after
    # SIGTERM for 10 s and more, and a stopped local cluster keeps no state worth a clean exit.
    for ((t = 0; t < 10; t++)); do
      pids=$(ours)
      [ -z "$pids" ] && break
      sleep 0.5
    done
    [ -n "$pids" ] && kill -9 $pids 2>/dev/null || true
  fi
  echo "ray cluster stopped"
}

case "${1:-}" in
  start) shift; start "$@" ;;
  status) "$RAY" status --address="127.0.0.1:$RAY_PORT" ;;
  stop) stop ;;
  *) echo "usage: $0 start [WORKERS] [CPUS_PER_NODE] | status | stop" >&2; exit 2 ;;
esac
