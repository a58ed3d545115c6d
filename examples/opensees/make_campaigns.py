"""Simulate the campaigns of the OpenSees frame example: python make_campaigns.py [FOLDER] [N]."""
import sys

from seqbayes.models.opensees_frame import write_campaigns

folder = sys.argv[1] if len(sys.argv) > 1 else "."
count = int(sys.argv[2]) if len(sys.argv) > 2 else 20
for path in write_campaigns(folder, count, seed=2026):
    print(path)
