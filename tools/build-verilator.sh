#!/usr/bin/env bash
# Build a pinned Verilator into a cache outside the repository, once.
#
#   bash tools/build-verilator.sh        (or: make verilator)
#
# Installs Verilator $VERSION into ${RHEO_CACHE:-$HOME/.cache/rheo-fpga}/verilator-$VERSION
# unless bin/verilator there already exists and reports $VERSION; then prints the
# path of the binary on stdout (progress goes to stderr, so
# `VERILATOR=$(bash tools/build-verilator.sh)` works).
#
# Why: cocotb 2.x refuses Verilator older than 5.036 and Debian bookworm ships 5.006.
# Source: Debian's source package (suite sid) from the mirror this machine already
# uses, fetched with a throw-away apt configuration (the system's lists are never
# touched). About 11 minutes on 2 cores.
#
# Robustness: the build happens in a temp dir, is installed with DESTDIR into
# "<prefix>.partial" and renamed to "<prefix>" only at the very end, so an
# interrupted build is never mistaken for a finished one. A lock file prevents
# two concurrent builds. The full build log is kept at <prefix>.build.log.
set -euo pipefail

VERSION=5.048
CACHE="${RHEO_CACHE:-$HOME/.cache/rheo-fpga}"
PREFIX="$CACHE/verilator-$VERSION"
PARTIAL="$PREFIX.partial"
LOG="$PREFIX.build.log"
BUILD_DEPS=(flex bison help2man libfl-dev autoconf g++ make)

say() { printf '[build-verilator] %s\n' "$*" >&2; }
die() { say "ERROR: $*"; exit 1; }

installed_ok() {
    local bin="$PREFIX/bin/verilator" out
    [[ -x "$bin" ]] || return 1
    out="$("$bin" --version 2>/dev/null)" || return 1
    [[ "$out" == "Verilator $VERSION "* ]]
}

if installed_ok; then
    say "Verilator $VERSION already installed in $PREFIX"
    echo "$PREFIX/bin/verilator"
    exit 0
fi

mkdir -p "$CACHE"
# One build at a time (a second caller waits, then finds the finished install).
exec 9>"$CACHE/.verilator-$VERSION.lock"
if ! flock -n 9; then
    say "another build is running (lock $CACHE/.verilator-$VERSION.lock); waiting..."
    flock 9
fi
if installed_ok; then
    say "Verilator $VERSION already installed in $PREFIX"
    echo "$PREFIX/bin/verilator"
    exit 0
fi

START=$(date +%s)
: >"$LOG"
say "build log: $LOG"
WORK="$(mktemp -d "${TMPDIR:-/tmp}/rheo-verilator-build.XXXXXX")"
cleanup() { rm -rf "$WORK"; }
trap cleanup EXIT

# Leftovers of an interrupted build, or a broken/mismatched install.
rm -rf "$PARTIAL"
if [[ -e "$PREFIX" ]]; then
    say "removing unusable install at $PREFIX"
    rm -rf "$PREFIX"
fi

# --- root helper for apt-get install -----------------------------------------
as_root() {
    if [[ $(id -u) -eq 0 ]]; then "$@"
    elif command -v sudo >/dev/null 2>&1; then sudo "$@"
    else die "need root to run: $*"
    fi
}

missing_pkgs() {
    local p
    for p in "$@"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || echo "$p"
    done
}

NEED=()
mapfile -t NEED < <(missing_pkgs dpkg-dev "${BUILD_DEPS[@]}")
if ((${#NEED[@]})); then
    say "installing build dependencies: ${NEED[*]}"
    if ! as_root apt-get install -y --no-install-recommends "${NEED[@]}" >>"$LOG" 2>&1; then
        say "apt-get install failed; running apt-get update first"
        as_root apt-get update >>"$LOG" 2>&1
        as_root apt-get install -y --no-install-recommends "${NEED[@]}" >>"$LOG" 2>&1 \
            || die "could not install ${NEED[*]} (see $LOG)"
    fi
fi

# --- fetch Debian's source package (sid) with a private apt configuration ----
mirror_uri() {
    local uri=""
    if [[ -r /etc/apt/sources.list.d/debian.sources ]]; then
        uri="$(awk '/^URIs:/ {for (i = 2; i <= NF; i++) print $i}' /etc/apt/sources.list.d/debian.sources \
               | grep -v -- '-security' | head -n1 || true)"
    fi
    if [[ -z "$uri" && -r /etc/apt/sources.list ]]; then
        uri="$(awk '$1 == "deb" { for (i = 2; i <= NF; i++) if ($i ~ /^[a-z]+:\/\//) { print $i; break } }' \
               /etc/apt/sources.list | grep -v -- '-security' | head -n1 || true)"
    fi
    echo "${uri:-http://deb.debian.org/debian}"
}
MIRROR="$(mirror_uri)"
KEYRING=/usr/share/keyrings/debian-archive-keyring.gpg

mkdir -p "$WORK/apt/lists/partial" "$WORK/src"
SIGNED=""
[[ -r "$KEYRING" ]] && SIGNED="[signed-by=$KEYRING] "
echo "deb-src ${SIGNED}${MIRROR} sid main" >"$WORK/apt/sources.list"
APT_OPTS=(
    -o "Dir::Etc::sourcelist=$WORK/apt/sources.list"
    -o "Dir::Etc::sourceparts=-"
    -o "Dir::State::Lists=$WORK/apt/lists"
    -o "Dir::Cache::pkgcache="
    -o "Dir::Cache::srcpkgcache="
)
# root's apt drops privileges to _apt, which cannot write into our temp dir.
[[ $(id -u) -eq 0 ]] && APT_OPTS+=(-o "APT::Sandbox::User=root")

say "fetching sid source index from $MIRROR"
apt-get "${APT_OPTS[@]}" update >>"$LOG" 2>&1 || die "apt-get update (private lists) failed (see $LOG)"

SRCVER="$(apt-cache "${APT_OPTS[@]}" showsrc verilator 2>>"$LOG" \
          | awk '/^Version:/ {print $2}' | grep -E "^([0-9]+:)?$VERSION-" | sort -V | tail -n1 || true)"
[[ -n "$SRCVER" ]] || die "Debian sid on $MIRROR no longer has verilator $VERSION;
  bump VERSION in $0 or point the deb-src line at snapshot.debian.org"

say "downloading Debian source package verilator=$SRCVER"
(cd "$WORK/src" && apt-get "${APT_OPTS[@]}" source --download-only "verilator=$SRCVER") >>"$LOG" 2>&1 \
    || die "apt-get source failed (see $LOG)"
DSC="$(ls "$WORK"/src/verilator_*.dsc | head -n1)"
say "unpacking $(basename "$DSC")"
(cd "$WORK/src" && dpkg-source -x "$DSC" verilator) >>"$LOG" 2>&1 || die "dpkg-source failed (see $LOG)"

# --- build -------------------------------------------------------------------
SRC="$WORK/src/verilator"
NPROC="$(nproc)"
run_step() {  # run_step NAME CMD...: quiet step, tail of the log on failure
    local name="$1"; shift
    say "$name ($(date +%T))"
    if ! (cd "$SRC" && "$@") >>"$LOG" 2>&1; then
        tail -n 40 "$LOG" >&2
        die "$name failed (full log: $LOG)"
    fi
}
# The prefix compiled into Verilator is the final one; DESTDIR stages the files.
run_step "autoconf" autoconf
run_step "configure --prefix=$PREFIX" ./configure --prefix="$PREFIX"
run_step "make -j$NPROC (the long part, ~11 min on 2 cores)" make -j"$NPROC"
run_step "make install (staged)" make install DESTDIR="$WORK/stage"

# Move the staged tree next to the final prefix (same filesystem), then rename.
mv "$WORK/stage$PREFIX" "$PARTIAL"
GOT="$(VERILATOR_ROOT="$PARTIAL/share/verilator" "$PARTIAL/bin/verilator" --version 2>/dev/null || true)"
[[ "$GOT" == "Verilator $VERSION "* ]] || die "staged binary reports '$GOT', expected $VERSION"
mv -T "$PARTIAL" "$PREFIX"
installed_ok || die "installed binary at $PREFIX/bin/verilator does not report $VERSION"

say "done in $(( $(date +%s) - START ))s: $("$PREFIX/bin/verilator" --version)"
echo "$PREFIX/bin/verilator"
