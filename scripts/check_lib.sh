# Shared by the ecosystem checks (sourced, not run): CI=true turns every skip
# into a failure, and packages a check needs are installed with apt-get there.
# Set CHECK_NAME before sourcing; it names the check in a failure.

in_ci() { [ -n "${CI:-}" ] && [ "${CI}" != "false" ]; }

# Outside CI: "skipped: REASON" and exit 0. Under CI=true: FAIL and exit 1.
skip() {
  if in_ci; then
    echo "FAIL: $1 (CI=$CI: the ${CHECK_NAME:-this} check must run)"
    exit 1
  fi
  echo "skipped: $1"
  exit 0
}

apt_install() {
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "== installing $* with apt-get"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "$@"
}

# node and npm: installed under CI, else the check is skipped.
need_node() {
  if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
    if in_ci; then apt_install nodejs npm; else skip "node/npm not installed (Debian: apt-get install nodejs npm)"; fi
  fi
}
