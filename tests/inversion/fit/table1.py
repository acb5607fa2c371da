"""The window the fit's compiled-path tests share: the Table 1 reed on the shipped bore.

The paper's Table 1 reed played on the shipped instrument at 100 kHz (:func:`table1_note`
in this folder's conftest); the window of N samples from sample W0, its history before it.
"""

from pathlib import Path

from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
ROOT = Path(__file__).resolve().parents[3]
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
W0, N = 20000, 2000
