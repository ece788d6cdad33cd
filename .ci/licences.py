#!/usr/bin/env python3
"""Fails unless every crate in the dependency tree (`cargo metadata`) may be used under a permissive licence.

An SPDX expression passes when one of its OR alternatives passes; an AND needs every part; `X WITH exception`
is judged as X. Run by .ci/run."""

import json
import re
import subprocess
import sys

PERMISSIVE = {
    "MIT", "MIT-0", "Apache-2.0", "BSD-2-Clause", "BSD-3-Clause", "ISC", "Zlib", "Unlicense", "0BSD", "CC0-1.0",
    "BSL-1.0", "Unicode-3.0", "Unicode-DFS-2016", "OFL-1.1", "Ubuntu-font-1.0",
}


def allowed(expr):
    expr = expr.replace("/", " OR ").strip()
    while expr.startswith("(") and expr.endswith(")") and balanced(expr[1:-1]):
        expr = expr[1:-1].strip()
    for op in (" OR ", " AND "):
        parts = split_top(expr, op)
        if len(parts) > 1:
            results = [allowed(p) for p in parts]
            return any(results) if op == " OR " else all(results)
    return re.split(r"\s+WITH\s+", expr)[0].strip() in PERMISSIVE


def balanced(s):
    depth = 0
    for c in s:
        depth += {"(": 1, ")": -1}.get(c, 0)
        if depth < 0:
            return False
    return depth == 0


def split_top(expr, op):
    parts, depth, start, i = [], 0, 0, 0
    while i < len(expr):
        c = expr[i]
        depth += {"(": 1, ")": -1}.get(c, 0)
        if depth == 0 and expr.startswith(op, i):
            parts.append(expr[start:i])
            start = i + len(op)
            i = start
            continue
        i += 1
    parts.append(expr[start:])
    return [p.strip() for p in parts]


def main():
    meta = json.loads(subprocess.run(["cargo", "metadata", "--format-version", "1", "--locked"], check=True,
                                     capture_output=True, text=True).stdout)
    used = {n["id"] for n in meta["resolve"]["nodes"]}
    bad = [f"{p['name']} {p['version']}: {p['license']}" for p in meta["packages"]
           if p["id"] in used and not allowed(p["license"] or "")]
    print(f"licences: {len(used)} crates checked, {len(bad)} not permissive")
    for b in bad:
        print("  " + b)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
