#!/usr/bin/env python3
"""Checks the include graph of the package against its layering.

Every file belongs to a layer: the core concerns (include/deblur_sr_mvs/core/<concern>/,
src/core/<concern>/, test/core/<concern>/), the ROS glue (include/deblur_sr_mvs/ros/,
src/ros/, src/nodelets/, src/nodes/) or the tools (src/tools/, src/ros_tools/).
Core code may include only the concerns below it:

    common <- geometry <- imaging <- estimation
    io (common, geometry, imaging), evaluation (common, geometry, imaging, io)

The ROS glue may include the core but never io, evaluation or the tools; nothing but
the tools (and tests) includes the tools' headers. Header include cycles are errors too.

Usage: scripts/check_layering.py [REPO]      exit 0 when clean, 1 with one line per problem.
"""
import pathlib
import re
import sys

ALLOWED = {
    "common": {"common"},
    "geometry": {"common", "geometry"},
    "imaging": {"common", "geometry", "imaging"},
    "estimation": {"common", "geometry", "imaging", "estimation"},
    "io": {"common", "geometry", "imaging", "io"},
    "evaluation": {"common", "geometry", "imaging", "io", "evaluation"},
    "ros": {"common", "geometry", "imaging", "estimation", "ros", "generated"},
}
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def layer_of(relative):
    parts = relative.parts
    if parts[:3] == ("include", "deblur_sr_mvs", "core") or parts[:2] in (("src", "core"), ("test", "core")):
        return parts[3] if parts[0] == "include" else parts[2]
    if parts[:3] == ("include", "deblur_sr_mvs", "ros") or parts[:2] in (("src", "ros"), ("src", "nodelets"), ("src", "nodes")):
        return "ros"
    if parts[:2] in (("src", "tools"), ("src", "ros_tools")):
        return "tools"
    return None


def layer_of_include(name):
    match = re.match(r"deblur_sr_mvs/core/([^/]+)/", name)
    if match:
        return match.group(1)
    if name.startswith("deblur_sr_mvs/ros/"):
        return "ros"
    if re.match(r"deblur_sr_mvs/[A-Za-z]+\.h$", name):
        return "generated"  # messages and dynamic_reconfigure headers
    return "tools"  # a tools-local header such as "tool_main.h"


def main():
    repo = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
    problems = []
    graph = {}
    for path in sorted(repo.glob("include/**/*.h")) + sorted(repo.glob("src/**/*.[ch]*")):
        relative = path.relative_to(repo)
        layer = layer_of(relative)
        includes = INCLUDE.findall(path.read_text(errors="replace"))
        if path.suffix == ".h" and relative.parts[0] == "include":
            graph[str(relative.relative_to("include"))] = [i for i in includes if i.startswith("deblur_sr_mvs/")]
        if layer in (None, "tools"):
            continue
        for name in includes:
            target = layer_of_include(name)
            if target not in ALLOWED[layer]:
                problems.append(f"{relative}: layer '{layer}' includes \"{name}\" (layer '{target}')")
    # Header cycles (depth-first search over the header graph).
    state = {}

    def visit(node, stack):
        state[node] = "open"
        for child in graph.get(node, []):
            if state.get(child) == "open":
                problems.append("include cycle: " + " -> ".join(stack[stack.index(child):] + [child]))
            elif child in graph and child not in state:
                visit(child, stack + [child])
        state[node] = "done"

    for node in graph:
        if node not in state:
            visit(node, [node])
    for problem in problems:
        print(problem)
    print(f"check_layering: {len(graph)} headers, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
