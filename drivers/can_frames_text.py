"""The CAN frame table in print: the Markdown tables docs/can-frames.md embeds and the DBC
file (`adxlgw dbc`, config/adxl-gateway.dbc), both made from drivers/can_frames.FRAMES
(tests/can/test_can_frames.py keeps the committed copies equal to them)."""

from __future__ import annotations

from .can_frames import DEFAULT_FRAMES, FRAMES, GATEWAY_NODE, PLC_NODE, FrameTable


def frames_markdown() -> str:
    """Frame and signal tables (embedded verbatim in docs/can-frames.md)."""
    lines = []
    for frame in FRAMES:
        cycle = f"every {frame.cycle_time_ms} ms" if frame.cycle_time_ms is not None else "on event"
        lines += [
            f"### {frame.name} — 0x{frame.frame_id:03X} ({frame.frame_id}), {frame.sender} → "
            f"{frame.receiver}, DLC {frame.dlc}, {cycle}, E2E data ID 0x{frame.data_id:04X}",
            "",
            frame.comment,
            "",
            "| Signal | Start bit | Bits | Signed | Factor | Range | Unit | Meaning |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for s in frame.signals:
            meaning = s.comment
            if s.choices:
                meaning += " Values: " + ", ".join(f"{raw} = {label}" for raw, label in s.choices) + "."
            lines.append(
                f"| {s.name} | {s.start_bit} | {s.length} | {'yes' if s.signed else 'no'} "
                f"| {_num(s.factor)} | {_num(s.minimum)} … {_num(s.maximum)} | {s.unit} | {meaning} |"
            )
        lines.append("")
    return "\n".join(lines)



def _num(value: float) -> str:
    """Plain decimal, no exponent (DBC readers differ on '1e-06')."""
    text = f"{value:.9f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def dbc_text(table: FrameTable = DEFAULT_FRAMES) -> str:
    """The DBC file describing every frame on the table's identifiers;
    config/adxl-gateway.dbc is this text for the default ones."""
    frames = table.frames
    out = [
        'VERSION ""',
        "",
        "",
        "NS_ :",
        "\tCM_",
        "\tBA_DEF_",
        "\tBA_",
        "\tVAL_",
        "\tBA_DEF_DEF_",
        "",
        "BS_:",
        "",
        f"BU_: {GATEWAY_NODE} {PLC_NODE}",
        "",
    ]
    for frame in frames:
        out.append("")
        out.append(f"BO_ {frame.frame_id} {frame.name}: {frame.dlc} {frame.sender}")
        for s in frame.signals:
            sign = "-" if s.signed else "+"
            out.append(
                f" SG_ {s.name} : {s.start_bit}|{s.length}@1{sign} ({_num(s.factor)},0) "
                f'[{_num(s.minimum)}|{_num(s.maximum)}] "{s.unit}" {frame.receiver}'
            )
    out.append("")
    out.append("")
    out.append(
        'CM_ "ADXL202 gateway (adxl-gateway). Generated from drivers/can_frames.py; '
        'every frame carries an AUTOSAR E2E profile 1 CRC (byte 0) and alive counter '
        '(byte 1 bits 0-3), data ID = CAN identifier.";'
    )
    out.append(f'CM_ BU_ {GATEWAY_NODE} "The adxl-gateway daemon.";')
    out.append(f'CM_ BU_ {PLC_NODE} "Controller consuming position, sending commands.";')
    for frame in frames:
        out.append(f'CM_ BO_ {frame.frame_id} "{frame.comment}";')
        for s in frame.signals:
            out.append(f'CM_ SG_ {frame.frame_id} {s.name} "{s.comment}";')
    out.append('BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;')
    out.append('BA_DEF_DEF_ "GenMsgCycleTime" 0;')
    for frame in frames:
        if frame.cycle_time_ms is not None:
            out.append(f'BA_ "GenMsgCycleTime" BO_ {frame.frame_id} {frame.cycle_time_ms};')
    for frame in frames:
        for s in frame.signals:
            if s.choices:
                pairs = " ".join(f'{raw} "{label}"' for raw, label in s.choices)
                out.append(f"VAL_ {frame.frame_id} {s.name} {pairs} ;")
    return "\n".join(out) + "\n"
