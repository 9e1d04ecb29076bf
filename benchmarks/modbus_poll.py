"""One read of a daemon's input registers over Modbus TCP, for the benchmarks that
score what a PLC would see: the named fields decoded, or None while the daemon is not
answering (starting, killed, restarting) — the next read connects again."""
from __future__ import annotations

import logging

from drivers.modbus_map import INPUT_REGISTERS, INPUT_SIZE, WordOrder, decode_register


class InputPoller:
    """`read()` → the values of `fields` (input register names) in that order, or None."""

    def __init__(self, port: int, fields: tuple[str, ...], timeout_s: float = 0.3):
        from pymodbus.client import ModbusTcpClient

        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # a daemon away is expected here
        self._regs = [r for name in fields for r in INPUT_REGISTERS if r.name == name]
        if len(self._regs) != len(fields):
            raise ValueError(f"not input registers: {sorted(set(fields) - {r.name for r in self._regs})}")
        self._client = ModbusTcpClient("127.0.0.1", port=port, timeout=timeout_s, retries=0)

    def read(self) -> tuple | None:
        client = self._client
        try:
            if not client.connected and not client.connect():
                return None
            answer = client.read_input_registers(0, count=INPUT_SIZE)
            if answer.isError():
                raise ConnectionError(str(answer))
        except Exception:  # noqa: BLE001 — whatever a daemon going away makes pymodbus raise
            client.close()
            return None
        words = answer.registers
        return tuple(decode_register(r, words[r.address:r.address + r.words], WordOrder.ABCD) for r in self._regs)

    def close(self) -> None:
        self._client.close()
