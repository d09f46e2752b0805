#!/usr/bin/env bash
# The Debian packages of the container images, derived so that they cannot drift from the project:
#
#   image-packages.sh build [SETUP_SH]   the build stage's packages: the first PACKAGES=(...) list of
#                                        scripts/setup.sh (toolchain, rendering, services, utilities,
#                                        tests) -- the same packages a developer machine gets
#   image-packages.sh runtime BINARY...  the runtime stage's packages: the Debian packages that own
#                                        every shared library the binaries load (ldd + dpkg -S)
#
# Prints one package per line. Fails if a library belongs to no package (then the runtime image
# could not provide it).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"

build_packages() {
  local setup="${1:-$here/../scripts/setup.sh}"
  [ -r "$setup" ] || { echo "image-packages: cannot read $setup" >&2; exit 2; }
  local block
  block="$(sed -n '/^PACKAGES=(/,/^)/p' "$setup")"
  [ -n "$block" ] || { echo "image-packages: no PACKAGES=( ... ) list in $setup" >&2; exit 1; }
  local PACKAGES=()
  eval "$block"
  printf '%s\n' "${PACKAGES[@]}"
}

# twins PATH: PATH, its resolved path, and their merged-/usr twins (/lib <-> /usr/lib): the name under
# which dpkg knows a file may be any of them.
twins() {
  local p="$1" real c
  real="$(readlink -f "$p")"
  for c in "$p" "$real"; do
    echo "$c"
    case "$c" in
      /usr/lib/*) echo "${c#/usr}" ;;
      /lib/*) echo "/usr$c" ;;
    esac
  done
}

runtime_packages() {
  [ $# -ge 1 ] || { echo "usage: image-packages.sh runtime BINARY..." >&2; exit 2; }
  local libs lib c line path rc=0 found
  libs="$(for b in "$@"; do ldd "$b"; done | awk '/=> \// { print $3 } /^\t\/[^ ]+ \(/ { print $1 }' | sort -u)"
  [ -n "$libs" ] || { echo "image-packages: ldd found no libraries in $*" >&2; exit 1; }
  # One dpkg -S for every candidate name (it reads its whole database on each call).
  local -A owner=()
  while IFS= read -r line; do
    case "$line" in diversion* | "") continue ;; esac
    path="/${line#*: /}"
    line="${line%%: /*}"
    owner["$path"]="${line%%[:,]*}"
  done < <(for lib in $libs; do twins "$lib"; done | sort -u | xargs dpkg -S 2>/dev/null)
  local out=""
  for lib in $libs; do
    found=""
    for c in $(twins "$lib"); do
      if [ -n "${owner[$c]:-}" ]; then found="${owner[$c]}"; break; fi
    done
    if [ -n "$found" ]; then
      out+="$found"$'\n'
    else
      echo "image-packages: $lib (needed by $*) belongs to no Debian package" >&2
      rc=1
    fi
  done
  printf '%s' "$out" | sort -u
  return "$rc"
}

case "${1:-}" in
  build) shift; build_packages "$@" ;;
  runtime) shift; runtime_packages "$@" ;;
  *) echo "usage: image-packages.sh build [SETUP_SH] | runtime BINARY..." >&2; exit 2 ;;
esac
