#!/usr/bin/env bash
# Install the Debian programs the test suite uses, where missing (idempotent):
#   tesseract-ocr  the second OCR engine (its tests run instead of skipping);
#   chromium       the headless browser that opens the HTML report in the report test;
#   fonts-noto-core, fonts-noto-cjk   the fonts of the multilingual synthetic scenes (synthetic-multi);
#   tesseract-ocr-{rus,ell,hin,ara,chi-sim}   Tesseract's Russian, Greek, Hindi, Arabic, Simplified
#                  Chinese language data (the OCR of those scenes; docs/ocr.md "Other scripts").
# Needs root (or sudo without a password) and apt; without them it says so and the tests that need
# these programs skip with that reason. STRINGS_BENCH_NO_SYSTEM_DEPS=1 skips this step.
set -uo pipefail
[ "${STRINGS_BENCH_NO_SYSTEM_DEPS:-0}" = "1" ] && { echo "[system] skipped (STRINGS_BENCH_NO_SYSTEM_DEPS=1)"; exit 0; }
missing=()
command -v tesseract >/dev/null 2>&1 || missing+=(tesseract-ocr)
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
[ -f /usr/share/fonts/truetype/noto/NotoSansDevanagari-Regular.ttf ] || missing+=(fonts-noto-core)
[ -f /usr/share/fonts/opentype/noto/NotoSansCJK-Regular.ttc ] || missing+=(fonts-noto-cjk)
langs=$(tesseract --list-langs 2>/dev/null || true)
for l in rus ell hin ara chi_sim; do
  echo "$langs" | grep -qx "$l" || missing+=("tesseract-ocr-${l//_/-}")
done
[ ${#missing[@]} -eq 0 ] && { echo "[system] tesseract (with its languages), chromium and the Noto fonts present"; exit 0; }
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
