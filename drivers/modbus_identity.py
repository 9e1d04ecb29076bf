"""Who this gateway is, on Modbus: device identification (function 43 / MEI 14) objects.

The Modbus Application Protocol (V1.1b3, 6.21) defines the objects and how a read code
selects them; pymodbus's own implementation reads a process-wide singleton, so the
selection is done here from this server's `DeviceIdentity` and only the response PDU
(its encoding) comes from pymodbus.

Objects served: 0x00 VendorName, 0x01 ProductCode, 0x02 MajorMinorRevision (basic);
0x03 VendorUrl, 0x04 ProductName, 0x05 ModelName, 0x06 UserApplicationName = the
configured device name (regular); 0x80 the register map version (extended, private).
Read codes: 1 basic, 2 regular, 3 extended (stream access: from the requested object
on, restarting at 0 when that object does not exist in the category), 4 one object
(individual access; exception 02 when it does not exist). Any other read code: 03.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import metadata

from pymodbus.constants import ExcCodes

BASIC, REGULAR, EXTENDED, SPECIFIC = 1, 2, 3, 4
#: 0x83: basic, regular and extended identification, stream and individual access.
CONFORMITY_LEVEL = 0x83
_CATEGORY_LAST = {BASIC: 0x02, REGULAR: 0x7F, EXTENDED: 0xFF}


def package_version() -> str:
    """The installed adxl-gateway version ("0.1.0"), "0.0.0+unknown" from a bare checkout."""
    try:
        return metadata.version("adxl-gateway")
    except metadata.PackageNotFoundError:
        return "0.0.0+unknown"


def version_numbers(version: str) -> tuple[int, int, int]:
    """(major, minor, patch) of a version string; missing or non-numeric parts read 0."""
    parts = [int(m.group()) if (m := re.match(r"\d+", p)) else 0 for p in version.split(".")[:3]]
    return tuple(min(p, 0xFFFF) for p in (parts + [0, 0, 0])[:3])  # type: ignore[return-value]


@dataclass(frozen=True, slots=True)
class DeviceIdentity:
    vendor_name: str = "adxl-gateway project"
    product_code: str = "ADXLGW"
    revision: str = ""  # "" = the installed package version
    vendor_url: str = ""  # none published yet: not sent
    product_name: str = "adxl-gateway"
    model_name: str = "ADXL202 serial-to-Modbus/CAN gateway"
    #: The configured [modbus] device_name, so a PLC can tell two gateways apart.
    device_name: str = ""
    map_version: int = 0

    @property
    def version(self) -> str:
        return self.revision or package_version()

    def objects(self) -> dict[int, bytes]:
        values = {
            0x00: self.vendor_name,
            0x01: self.product_code,
            0x02: self.version,
            0x03: self.vendor_url,
            0x04: self.product_name,
            0x05: self.model_name,
            0x06: self.device_name,
            0x80: f"register map {self.map_version}",
        }
        # an empty object is not sent (a device name may be unset), except the basic ones
        return {k: v.encode("ascii", "replace") for k, v in values.items() if v or k <= 0x02}


def device_information(identity: DeviceIdentity, read_code: int, object_id: int) -> dict[int, bytes] | ExcCodes:
    """The objects a request (read code, object id) asks for, or the exception code."""
    objects = identity.objects()
    if read_code == SPECIFIC:
        return {object_id: objects[object_id]} if object_id in objects else ExcCodes.ILLEGAL_ADDRESS
    last = _CATEGORY_LAST.get(read_code)
    if last is None:
        return ExcCodes.ILLEGAL_VALUE
    in_category = [k for k in sorted(objects) if k <= last]
    if object_id not in in_category:
        object_id = 0  # the spec: an unknown start object restarts the stream at 0
    return {k: objects[k] for k in in_category if k >= object_id}
