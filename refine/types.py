"""The array type of the package: ``Array``, a float64 numpy array (shapes are stated where used)."""

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
