"""The wiring diagram: a sensor board on a Raspberry Pi's 40-pin header (I2C bus 1),
as a self-contained SVG written with no dependency.

Pins (Raspberry Pi GPIO header, the same on every 40-pin Pi): 1 = 3V3, 3 = GPIO2 / SDA1,
5 = GPIO3 / SCL1, 6 = GND.  The breakout boards imucald supports (GY-521 MPU-6050, GY-85
"9DOF", GY-273, MPU-9250 modules) carry their own regulator and pull-ups and take 3.3 V on
VCC; AD0 / SDO straps the address (MPU: low 0x68, high 0x69)."""
from __future__ import annotations

from typing import List, Tuple

__all__ = ["WIRES", "wiring_svg"]

#: (Pi header pin, Pi signal, board pin, colour)
WIRES: Tuple[Tuple[int, str, str, str], ...] = (
    (1, "3V3", "VCC", "#d62728"),
    (3, "GPIO2 SDA", "SDA", "#1f77b4"),
    (5, "GPIO3 SCL", "SCL", "#ff7f0e"),
    (6, "GND", "GND", "#333333"),
)


def wiring_svg(board_label: str = "MPU-6050 (GY-521), GY-85 9DOF, GY-273, MPU-9250 board") -> str:
    """The SVG text (deterministic: no date, no random ids)."""
    W, H = 760, 330
    out: List[str] = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" '
        'font-family="sans-serif" font-size="13">',
        '<title>imucald wiring: sensor board to the Raspberry Pi I2C pins</title>',
        f'<rect x="0" y="0" width="{W}" height="{H}" fill="white"/>',
        # the Pi's header: 2 columns x 4 rows shown (pins 1-8), pin 1 square
        '<rect x="30" y="40" width="230" height="250" rx="10" fill="#2e7d32" opacity="0.9"/>',
        '<text x="145" y="30" text-anchor="middle" font-weight="bold">Raspberry Pi 40-pin header</text>',
    ]
    names = {1: "3V3", 2: "5V", 3: "SDA1", 4: "5V", 5: "SCL1", 6: "GND", 7: "GPIO4", 8: "TXD"}
    used = {w[0] for w in WIRES}
    pin_xy = {}
    for pin in range(1, 9):
        row, col = (pin - 1) // 2, (pin - 1) % 2
        x, y = 130 + col * 40, 80 + row * 50
        pin_xy[pin] = (x, y)
        shape = (f'<rect x="{x - 9}" y="{y - 9}" width="18" height="18"' if pin == 1 else
                 f'<circle cx="{x}" cy="{y}" r="9"')
        fill = "#ffd54f" if pin in used else "#9e9e9e"
        out.append(f'{shape} fill="{fill}" stroke="black"/>')
        tx = x - 18 if col == 0 else x + 18
        anchor = "end" if col == 0 else "start"
        out.append(f'<text x="{tx}" y="{y + 4}" text-anchor="{anchor}" fill="white">{pin} {names[pin]}</text>')
    out.append('<text x="145" y="280" text-anchor="middle" fill="white" font-size="11">'
               '(pins 1-8 of 40; pin 1 is the square pad)</text>')
    bx, by = 520, 60
    out.append(f'<rect x="{bx}" y="{by}" width="200" height="210" rx="8" fill="#1565c0" opacity="0.9"/>')
    out.append(f'<text x="{bx + 100}" y="{by - 12}" text-anchor="middle" font-weight="bold">sensor board</text>')
    for k, (pin, sig, bpin, colour) in enumerate(WIRES):
        y = by + 35 + k * 40
        px, py = pin_xy[pin]
        out.append(f'<circle cx="{bx}" cy="{y}" r="7" fill="#ffd54f" stroke="black"/>')
        out.append(f'<text x="{bx + 14}" y="{y + 4}" fill="white">{bpin}</text>')
        start = px + 9 if pin % 2 == 0 else px
        out.append(f'<path d="M {start} {py} C {start + 180} {py}, {bx - 160} {y}, {bx - 7} {y}" '
                   f'stroke="{colour}" stroke-width="4" fill="none"/>')
        out.append(f'<text x="{(start + bx) / 2 + 40}" y="{(py + y) / 2 - 6}" fill="{colour}" '
                   f'font-size="11">{sig}</text>')
    out.append(f'<text x="{bx + 100}" y="{by + 205}" text-anchor="middle" fill="white" font-size="11">'
               'AD0/SDO: address strap</text>')
    out.append(f'<text x="{W / 2}" y="{H - 8}" text-anchor="middle" font-size="12">{board_label}: '
               'VCC to 3.3 V (pin 1), never 5 V on SDA/SCL</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"
