#!/usr/bin/env bash
# Install the Debian programs the test suite uses, where missing (idempotent):
#   tesseract-ocr  the second OCR engine (its tests run instead of skipping);
#   chromium       the headless browser that opens the HTML report in the report test.
# Needs root (or sudo without a password) and apt; without them it says so and the tests that need
# these programs skip with that reason. STRINGS_BENCH_NO_SYSTEM_DEPS=1 skips this step.
set -uo pipefail
[ "${STRINGS_BENCH_NO_SYSTEM_DEPS:-0}" = "1" ] && { echo "[system] skipped (STRINGS_BENCH_NO_SYSTEM_DEPS=1)"; exit 0; }
missing=()
command -v tesseract >/dev/null 2>&1 || missing+=(tesseract-ocr)
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
[ ${#missing[@]} -eq 0 ] && { echo "[system] tesseract and chromium present"; exit 0; }
if ! command -v apt-get >/dev/null 2>&1; then
  echo "[system] apt-get not found: cannot install ${missing[*]}; the tests that need them will skip"; exit 0
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then SUDO="sudo -n"; else
    echo "[system] not root and no passwordless sudo: cannot install ${missing[*]}; the tests that need them will skip"; exit 0
  fi
fi
echo "[system] installing ${missing[*]} with apt-get (about a minute)"
export DEBIAN_FRONTEND=noninteractive
if ! $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}" >/tmp/strings-bench-apt.log 2>&1; then
  # a fresh machine may have no package lists yet
  $SUDO apt-get update -q >>/tmp/strings-bench-apt.log 2>&1
  $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}" >>/tmp/strings-bench-apt.log 2>&1 \
    || echo "[system] apt-get failed (log: /tmp/strings-bench-apt.log); the tests that need ${missing[*]} will skip"
fi
exit 0
