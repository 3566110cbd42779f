"""Checksum of the product's TestTorqueRequest frame.

Byte 0 of the 8-byte payload holds CRC-8/SAE-J1850 (polynomial 0x1D, initial value 0xFF, final
XOR 0xFF, not reflected) computed over payload bytes 1..7. The ECU drops a frame whose checksum
does not match (and one whose alive counter does not advance).
"""

from crccheck.crc import Crc8SaeJ1850

#: Index of the payload byte that carries the checksum.
CHECKSUM_BYTE = 0
#: Length of a protected payload, bytes.
PAYLOAD_LENGTH = 8


def _check_length(payload: bytes | bytearray) -> None:
    if len(payload) != PAYLOAD_LENGTH:
        raise ValueError(f"a checksummed payload has {PAYLOAD_LENGTH} bytes, got {len(payload)}")


def compute_checksum(payload: bytes | bytearray) -> int:
    """Return the checksum of a payload.

    Parameters
    ----------
    payload : bytes or bytearray
        The 8-byte payload; byte 0 (the checksum itself) is ignored.

    Returns
    -------
    int
        CRC-8/SAE-J1850 over bytes 1..7, 0..255.

    Raises
    ------
    ValueError
        If the payload is not 8 bytes long.
    """
    _check_length(payload)
    return Crc8SaeJ1850.calc(payload[CHECKSUM_BYTE + 1 :])


def apply_checksum(payload: bytes | bytearray) -> bytes:
    """Return a copy of the payload with the checksum written into byte 0.

    Parameters
    ----------
    payload : bytes or bytearray
        The 8-byte payload; its byte 0 is overwritten in the copy.

    Returns
    -------
    bytes
        The payload with a valid checksum.

    Raises
    ------
    ValueError
        If the payload is not 8 bytes long.
    """
    protected = bytearray(payload)
    protected[CHECKSUM_BYTE] = compute_checksum(payload)
    return bytes(protected)


def verify_checksum(payload: bytes | bytearray) -> bool:
    """Tell whether byte 0 of a payload holds the checksum of bytes 1..7.

    Parameters
    ----------
    payload : bytes or bytearray
        The received payload.

    Returns
    -------
    bool
        True if the checksum matches; False if it does not or if the payload is not 8 bytes long.
    """
    if len(payload) != PAYLOAD_LENGTH:
        return False
    return payload[CHECKSUM_BYTE] == compute_checksum(payload)
