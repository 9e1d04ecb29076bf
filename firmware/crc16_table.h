/* CRC-16/CCITT-FALSE (polynomial 0x1021) by table, built by the compiler.
 *
 * The table entry for index i (the CRC's high byte XOR the next byte) is the register
 * after shifting i << 8 eight times through the polynomial; for 0x1021 that is, with
 * x = i ^ (i >> 4), (x << 12) ^ (x << 5) ^ x (the polynomial's three terms). The table is
 * split into high and low bytes so that the 8051 updates the CRC with 8-bit moves only:
 *   i = crc_hi ^ byte;  crc_hi = crc_lo ^ CRC_HI[i];  crc_lo = CRC_LO[i];
 * tests/board/test_firmware.py checks every frame's CRC with the project's decoder (binascii).
 */
#ifndef CRC16_TABLE_H
#define CRC16_TABLE_H

#define CRC_FOLD(i) ((unsigned int)((i) ^ ((i) >> 4)))
#define CRC_ENTRY(i) (((CRC_FOLD(i) << 12) ^ (CRC_FOLD(i) << 5) ^ CRC_FOLD(i)) & 0xFFFFu)
#define CRC_HI_OF(i) ((unsigned char)(CRC_ENTRY(i) >> 8))
#define CRC_LO_OF(i) ((unsigned char)(((CRC_FOLD(i) << 5) ^ CRC_FOLD(i)) & 0xFFu)) /* x << 12 has no low byte */

#define CRC_ROW4(F, i) F(i), F((i) + 1), F((i) + 2), F((i) + 3)
#define CRC_ROW16(F, i) CRC_ROW4(F, i), CRC_ROW4(F, (i) + 4), CRC_ROW4(F, (i) + 8), CRC_ROW4(F, (i) + 12)
#define CRC_ROW64(F, i) CRC_ROW16(F, i), CRC_ROW16(F, (i) + 16), CRC_ROW16(F, (i) + 32), CRC_ROW16(F, (i) + 48)
#define CRC_TABLE(F) CRC_ROW64(F, 0), CRC_ROW64(F, 64), CRC_ROW64(F, 128), CRC_ROW64(F, 192)

#endif
