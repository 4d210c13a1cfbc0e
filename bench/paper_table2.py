"""Table 2 of Deng & Latecki 2017 (ablation on NYUv2): AP@0.25 per class, in a3d's CLASSES order.

Keyed by bench/ablation.py's variant names; puts a synthetic set's per-class results beside the
paper's (bench/ablation.py --per-class, bench/gravity_lifting.py --per-class).
"""

_ROWS = {  # as printed in the paper
    "color": "27.9 64.5 24.5 1.5 33.1 46.0 20.3 1.7 28.7 32.1 24.6 3.0 43.4 27.7 49.6 46.7 27.6 1.3 66.0",
    "no-context": "38.9 85.2 37.5 11.4 46.5 47.1 29.9 4.2 43.3 37.3 30.8 1.3 59.8 44.1 57.7 63.8 39.4 11.6 "
    "75.5",
    "full": "36.1 84.5 40.6 4.9 46.4 44.8 33.1 10.2 44.9 33.3 29.4 3.6 60.6 46.3 58.3 61.8 43.2 16.3 79.7",
    "no-3dreg": "8.3 5.0 14.3 2.1 14.1 3.6 0.6 0.7 4.1 29.5 27.1 2.4 23.0 31.4 20.5 34.5 4.6 1.7 67.6",
}
# Rows "img", "img+d", "img+d+ct" and "img+d+ct-3dreg" (the initial boxes).
PAPER_AP = {variant: tuple(float(ap) for ap in row.split()) for variant, row in _ROWS.items()}
# The mAPs as printed; "img+d"'s per-class row averages to 40.3, not its printed 40.1.
PAPER_MAP = {"color": 30.0, "no-context": 40.1, "full": 40.9, "no-3dreg": 15.5}
