"""The array type of the typed layers: samples, states and parameter vectors are float64.

`np.ndarray` alone says nothing of its elements; `FloatArray` says what the kernels and the
analysis rely on (numba compiles one specialisation per dtype, and an int or float32 array
would compile another and round differently).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
