#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# include_rules.sh SOURCE_DIR — the layers' include rules, the include twin of core_symbols.sh:
# every include points down (host/cli -> host/tools -> host/core -> host/include; backends -> host/core;
# host/mpi -> host/core).
#   host/include: only the public headers (mbvh/...) and the standard library
#   host/core:    no backend, tool, program or MPI layer
#   backends:     no tool or program
#   host/tools:   no backend, program or MPI layer (tools reach backends through the registry; mbvh_tools links no MPI)
#   host/mpi:     no backend, tool or program (mbvh::mpi: the core, and backends through the interface)
#   bindings:     only the public headers (mbvh/...), as any user of the library (C, Python)
# Each rule is first shown a line that breaks it, so the check cannot pass by matching nothing.
set -euo pipefail
src="$1"
# each rule: a folder, what it may not include, and a line that breaks the rule
dirs=(host/include host/core backends host/tools bindings host/mpi)
patterns=('#include "(host|backends)/' '#include "(backends|host/tools|host/cli|host/mpi)/' '#include "host/(tools|cli)/'
          '#include "(backends|host/cli|host/mpi)/' '#include ["<](host|backends|tests)/' '#include "(backends|host/tools|host/cli)/')
planted=('#include "host/core/layouts.h"' '#include "host/mpi/calls.h"' '#include "host/tools/check.h"'
         '#include "host/mpi/calls.h"' '#include "host/core/layouts.h"' '#include "host/tools/render.h"')
status=0
for i in "${!dirs[@]}"; do
  dir="${dirs[$i]}" pattern="${patterns[$i]}"
  grep -qE "^[[:space:]]*$pattern" <<<"${planted[$i]}" \
    || { echo "error: the rule for $dir does not see the line ${planted[$i]}: the check is blind" >&2; exit 1; }
  [ -d "$src/$dir" ] || { echo "error: $src/$dir is missing: the check is blind" >&2; exit 1; }
  if grep -rnE --include='*.h' --include='*.c' --include='*.cpp' --include='*.hpp' "^[[:space:]]*$pattern" "$src/$dir"; then
    echo "error: $dir includes what lies above it (the lines above; pattern: $pattern)" >&2
    status=1
  fi
done
[ "$status" = 0 ] && echo "include rules: host/include, host/core, backends, host/tools, bindings and host/mpi include only what lies below them"
exit "$status"
