/* CRC-16/CCITT-FALSE (polynomial 0x1021) by table, built by the compiler.
 *
 * CRC_STEP(x) is one shift of the 16-bit register with the polynomial folded in when
 * the top bit falls out; eight of them give the table entry for one byte. The table is
 * split into high and low bytes so that the 8051 updates the CRC with 8-bit moves only:
 *   i = crc_hi ^ byte;  crc_hi = crc_lo ^ CRC_HI[i];  crc_lo = CRC_LO[i];
 * The values are checked against Python's binascii.crc_hqx by tests/test_firmware.py
 * through the frames the firmware sends (each frame's CRC must match).
 */
#ifndef CRC16_TABLE_H
#define CRC16_TABLE_H

#define CRC_STEP(x) ((((x) << 1) ^ ((((x) >> 15) & 1u) * 0x1021u)) & 0xFFFFu)
#define CRC_ENTRY(i) CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(CRC_STEP(((unsigned long)(i)) << 8))))))))
#define CRC_HI_OF(i) ((unsigned char)(CRC_ENTRY(i) >> 8))
#define CRC_LO_OF(i) ((unsigned char)(CRC_ENTRY(i) & 0xFFu))

#define CRC_ROW4(F, i) F(i), F((i) + 1), F((i) + 2), F((i) + 3)
#define CRC_ROW16(F, i) CRC_ROW4(F, i), CRC_ROW4(F, (i) + 4), CRC_ROW4(F, (i) + 8), CRC_ROW4(F, (i) + 12)
#define CRC_ROW64(F, i) CRC_ROW16(F, i), CRC_ROW16(F, (i) + 16), CRC_ROW16(F, (i) + 32), CRC_ROW16(F, (i) + 48)
#define CRC_TABLE(F) CRC_ROW64(F, 0), CRC_ROW64(F, 64), CRC_ROW64(F, 128), CRC_ROW64(F, 192)

#endif
