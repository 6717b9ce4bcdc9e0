#!/usr/bin/env bash
# System packages the test suite needs beyond the runtime ones: Debian's chromium, to check that
# report.html renders in a real browser. apt-get when root; otherwise name the package and stop.
set -euo pipefail
if command -v chromium >/dev/null || command -v chromium-browser >/dev/null; then exit 0; fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
  echo "[setup] installing chromium for the report's browser test"
  if ! apt-get install -y -q --no-install-recommends chromium >/tmp/bijcr-apt-test.log 2>&1; then
    apt-get update -q >>/tmp/bijcr-apt-test.log 2>&1 || true
    apt-get install -y -q --no-install-recommends chromium >>/tmp/bijcr-apt-test.log 2>&1 || {
      echo "[setup] apt-get could not install chromium; see /tmp/bijcr-apt-test.log" >&2; exit 1; }
  fi
else
  echo "[setup] the tests need Debian's chromium package: sudo apt-get install chromium" >&2
  exit 1
fi
