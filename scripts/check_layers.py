#!/usr/bin/env python3
"""Checks the source tree's shape:
  - layers point one way: common/ is the floor, then wire/, then worker/ and master/ (which do not
    include each other), then client/;
  - no include cycles between the project's modules (a header and its .cpp count as one);
  - no source file in common/ wire/ worker/ master/ client/ longer than MAX_LINES.
Exits non-zero naming every violation.

    python3 scripts/check_layers.py [REPO_ROOT]
"""
import os
import re
import sys

MAX_LINES = 700
# What each folder may include of the project (besides itself); the generated protos are "epr/".
ALLOWED = {
    "common": set(),
    "wire": {"common", "epr"},
    "worker": {"common", "wire", "epr"},
    "master": {"common", "wire", "epr"},
    "client": {"common", "wire", "worker", "master", "epr"},
}
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def main() -> int:
    root = sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    files = {}
    for top in ALLOWED:
        for dirpath, _, names in os.walk(os.path.join(root, top)):
            for n in names:
                if n.endswith((".h", ".cpp")):
                    rel = os.path.relpath(os.path.join(dirpath, n), root)
                    with open(os.path.join(root, rel), encoding="utf-8") as f:
                        files[rel] = f.read()
    problems = []
    graph = {}
    for rel, text in files.items():
        layer = rel.split("/")[0]
        lines = text.count("\n")
        if lines > MAX_LINES:
            problems.append(f"{rel}: {lines} lines, more than {MAX_LINES}")
        mod = os.path.splitext(rel)[0]
        graph.setdefault(mod, [])
        for inc in INCLUDE.findall(text):
            top = inc.split("/")[0]
            if top in ALLOWED or top == "epr":
                if top != layer and top not in ALLOWED[layer]:
                    problems.append(f"{rel}: includes {inc} ({layer}/ may not include {top}/)")
                target = os.path.splitext(inc)[0]
                if inc in files and target != mod:
                    graph[mod].append(target)
    # Cycles: depth-first search with colours.
    state = {}
    stack = []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in graph.get(node, []):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt):] + [nxt]
                problems.append("include cycle: " + " -> ".join(cycle))
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    for p in problems:
        print(p, file=sys.stderr)
    print(f"check_layers: {len(files)} files, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
