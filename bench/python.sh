# SPDX-License-Identifier: MIT
# python.sh — sourced by the bench scripts: sets PY to Debian's python3 (with Debian's
# python3-matplotlib, installed with apt-get if missing), not another python3 earlier on PATH;
# $PYTHON overrides.
PY="${PYTHON:-$( [ -x /usr/bin/python3 ] && echo /usr/bin/python3 || echo python3)}"
"$PY" -c "import matplotlib" 2>/dev/null || { echo "installing python3-matplotlib (apt-get)" >&2;
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-matplotlib > /dev/null; }
