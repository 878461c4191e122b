#!/bin/sh
# Make sure Debian's headless Chromium is present for the browser test
# (tests/test_dashboard_browser.py).
# Playwright drives /usr/bin/chromium; no browser is ever downloaded by a test tool.
set -e
if [ -x /usr/bin/chromium ]; then
  exit 0
fi
echo "Installing Debian's chromium for the browser test..." >&2
if [ "$(id -u)" = 0 ]; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
elif command -v sudo >/dev/null 2>&1; then
  sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
else
  echo "chromium is missing and cannot be installed (not root, no sudo): apt-get install chromium" >&2
  exit 1
fi
