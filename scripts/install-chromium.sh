#!/usr/bin/env bash
# Installs Debian's headless Chromium for the dashboard's browser test (tests/service/test_dashboard_browser.py).
# The test drives Chromium over the DevTools protocol on a pipe (--remote-debugging-pipe), so no chromedriver and no
# Python browser library is needed. Nothing is downloaded from outside Debian's archive: power plants and CI are
# offline but for the package registries. Idempotent: does nothing when a chromium binary is already on PATH.
# Without root or apt-get it says so in one line and exits 0: the test then skips with its own one-line reason.
set -euo pipefail

if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "install-chromium: no apt-get on this machine; the dashboard browser test will skip" >&2
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "install-chromium: not root, cannot apt-get install chromium; the dashboard browser test will skip" >&2
    exit 0
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
# fonts-dejavu-core: readable text in the screenshot (a bare image may have no font Chromium can use)
apt-get install -y -qq --no-install-recommends chromium fonts-dejavu-core >/dev/null
command -v chromium >/dev/null
