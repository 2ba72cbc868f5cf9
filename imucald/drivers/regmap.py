"""Declarative register maps, shared by each chip's driver and its emulator.

A chip is data: registers with an address, a power-on value and named bit
fields given as *masks* (the shift is derived, as in pimoroni's i2cdevice), so
a field is written down once, next to the datasheet or kernel source it comes
from, and both the driver and the emulator read it from here.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Mapping, Optional

__all__ = ["Field", "Register", "RegisterMap"]


@dataclass(frozen=True)
class Field:
    mask: int

    @property
    def shift(self) -> int:
        return (self.mask & -self.mask).bit_length() - 1

    def get(self, value: int) -> int:
        return (value & self.mask) >> self.shift

    def put(self, value: int, fv: int) -> int:
        if fv << self.shift & ~self.mask:
            raise ValueError(f"value {fv} does not fit mask 0x{self.mask:02X}")
        return (value & ~self.mask) | (fv << self.shift)


@dataclass(frozen=True)
class Register:
    name: str
    addr: int
    reset: int = 0x00                 #: power-on value
    fields: Mapping[str, Field] = field(default_factory=dict)
    read_only: bool = False
    length: int = 1                   #: bytes (a data block starting here)


class RegisterMap:
    """Registers of one chip by name; ``regmap.CONFIG.addr``, ``regmap.field(...)``."""

    def __init__(self, chip: str, *registers: Register):
        self.chip = chip
        self._by_name: Dict[str, Register] = {r.name: r for r in registers}
        self._by_addr: Dict[int, Register] = {r.addr: r for r in registers}

    def __getattr__(self, name: str) -> Register:
        try:
            return self._by_name[name]
        except KeyError:
            raise AttributeError(f"{self.chip} has no register {name}") from None

    def __iter__(self):
        return iter(self._by_name.values())

    def at(self, addr: int) -> Optional[Register]:
        return self._by_addr.get(addr)

    def encode(self, reg: str, base: Optional[int] = None, **fields: int) -> int:
        """Register value with the named fields set (others from ``base`` or reset)."""
        r = self._by_name[reg]
        v = r.reset if base is None else base
        for k, fv in fields.items():
            v = r.fields[k].put(v, fv)
        return v

    def decode(self, reg: str, value: int, name: str) -> int:
        return self._by_name[reg].fields[name].get(value)

    def power_on(self) -> bytearray:
        """A 256-byte register file holding every register's power-on value."""
        mem = bytearray(256)
        for r in self._by_name.values():
            mem[r.addr] = r.reset
        return mem
