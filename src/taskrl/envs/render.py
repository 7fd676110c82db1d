"""Pictures of the native environments as RGB arrays (``render_mode="rgb_array"``), for videos.

Small and dependency-free: numpy draws discs and squares on a white canvas.
"""

from __future__ import annotations

import numpy as np

__all__ = ["draw_bits", "draw_points"]

SIZE = 160
WHITE, BLUE, GREEN, GREY, BLACK = (255, 255, 255), (40, 90, 200), (60, 170, 80), (215, 215, 215), (30, 30, 30)


def _pixel(xy: np.ndarray) -> np.ndarray:
    """[-1, 1]^2 -> pixel coordinates (y up)."""
    x, y = (np.asarray(xy, dtype=np.float64) + 1.0) / 2.0 * (SIZE - 1)
    return np.array([x, SIZE - 1 - y])


def draw_points(point: np.ndarray, targets: list[tuple[np.ndarray, float, bool]]) -> np.ndarray:
    """A ``[SIZE, SIZE, 3]`` picture of the box ``[-1, 1]^2``: each target a disc (``(centre, radius, active)``,
    green if active, grey otherwise), the point a blue disc."""
    image = np.full((SIZE, SIZE, 3), WHITE, dtype=np.uint8)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]

    def disc(centre: np.ndarray, radius_px: float, colour: tuple[int, int, int]) -> None:
        cx, cy = _pixel(centre)
        image[(cols - cx) ** 2 + (rows - cy) ** 2 <= radius_px**2] = colour

    for centre, radius, active in targets:
        disc(centre, max(radius / 2.0 * (SIZE - 1), 3.0), GREEN if active else GREY)
    disc(point, 4.0, BLUE)
    return image


def draw_bits(state: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Two rows of squares: the current bits (top) and the target (bottom), black for 1."""
    n, cell = len(state), 16
    image = np.full((2 * cell + 12, n * cell + 8, 3), WHITE, dtype=np.uint8)
    for row, bits in enumerate((state, goal)):
        top = 4 + row * (cell + 4)
        for i, bit in enumerate(np.asarray(bits).astype(int)):
            left = 4 + i * cell
            image[top : top + cell - 2, left : left + cell - 2] = BLACK if bit else GREY
    return image
