#!/usr/bin/env python3
"""Clang's thread-safety analysis over the project's sources.

Reads the compile commands of a build folder (CMAKE_EXPORT_COMPILE_COMMANDS), runs each project
source that uses the annotations (it or its header includes common/check.h) through clang++ -fsyntax-only with -Wthread-safety as an error, two at a time, and exits
non-zero if any file breaks a lock annotation (common/check.h: EPR_GUARDED_BY, EPR_REQUIRES, ...).

    python3 scripts/check_thread_safety.py build [PATH_PREFIX...]
"""
import concurrent.futures
import json
import os
import shlex
import subprocess
import sys

FOLDERS = ("common/", "wire/", "worker/", "master/", "client/")


def annotated(root: str, rel: str) -> bool:
    """True if the source, or a project header it includes, includes common/check.h."""
    def read(path):
        try:
            with open(os.path.join(root, path), encoding="utf-8") as f:
                return f.read()
        except FileNotFoundError:
            return ""
    text = read(rel)
    if '#include "common/check.h"' in text:
        return True
    for line in text.splitlines():
        if line.startswith('#include "') and '#include "common/check.h"' in read(line.split('"')[1]):
            return True
    return False


def main() -> int:
    build = sys.argv[1] if len(sys.argv) > 1 else "build"
    only = tuple(sys.argv[2:]) or FOLDERS
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(build, "compile_commands.json")) as f:
        commands = json.load(f)
    jobs = []
    for c in commands:
        rel = os.path.relpath(c["file"], root)
        if not rel.startswith(only) or not rel.endswith(".cpp") or not annotated(root, rel):
            continue
        args = shlex.split(c["command"]) if "command" in c else list(c["arguments"])
        # Drop the compiler (and a launcher such as ccache), the output and the dependency-file flags.
        while args and not args[0].startswith("-"):
            args.pop(0)
        kept, skip = [], False
        for a in args:
            if skip:
                skip = False
                continue
            if a in ("-o", "-MF", "-MT", "-MQ"):
                skip = True
                continue
            if a in ("-c", "-MD", "-MMD") or a == c["file"] or a.startswith("-Wno-psabi"):
                continue
            kept.append(a)
        jobs.append((rel, c["directory"],
                     ["clang++", "-fsyntax-only", "-Wthread-safety", "-Werror=thread-safety", "-Wno-unknown-warning-option"]
                     + kept + [c["file"]]))
    if not jobs:
        print("check_thread_safety: no project sources in", build, file=sys.stderr)
        return 2

    def run(job):
        rel, cwd, cmd = job
        r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
        return rel, r.returncode, r.stderr

    failed = 0
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        for rel, code, err in pool.map(run, jobs):
            if code != 0:
                failed += 1
                print(f"--- {rel}\n{err}", file=sys.stderr)
    print(f"check_thread_safety: {len(jobs)} files, {failed} with errors")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
