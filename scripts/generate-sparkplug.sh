#!/usr/bin/env bash
# Regenerates drivers/sparkplug/sparkplug_b_pb2.py from drivers/sparkplug/sparkplug_b.proto.
# Run it only when the .proto changes (tests/mqtt/test_mqtt_payload.py fails when the two differ).
# The generated module is committed (docs/decisions/0060-sparkplug-generated-code.md): the
# gateway then needs only the protobuf runtime, not a compiler. The compiler is grpcio-tools'
# bundled protoc, pinned here; its protobuf version must not be newer than the runtime's
# in constraints.txt (the generated code checks that when it is imported).
set -euo pipefail
cd "$(dirname "$0")/.."
GRPCIO_TOOLS_VERSION=1.85.1
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q --disable-pip-version-check "grpcio-tools==$GRPCIO_TOOLS_VERSION"
"$work/venv/bin/python" -m grpc_tools.protoc -Idrivers/sparkplug --python_out="$work" drivers/sparkplug/sparkplug_b.proto
digest="$(sha256sum drivers/sparkplug/sparkplug_b.proto | cut -d' ' -f1)"
{
    echo "# Made by scripts/generate-sparkplug.sh (grpcio-tools $GRPCIO_TOOLS_VERSION) from sparkplug_b.proto"
    echo "# proto-sha256: $digest"
    echo "# Derived from Eclipse Tahu's sparkplug_b.proto, EPL-2.0 (LICENSE beside it)."
    cat "$work/sparkplug_b_pb2.py"
} > drivers/sparkplug/sparkplug_b_pb2.py
echo "wrote drivers/sparkplug/sparkplug_b_pb2.py" >&2
