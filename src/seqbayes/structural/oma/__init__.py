"""Operational modal analysis: from ambient records to modes with standard errors, with defaults chosen from the record.

The path (docs/oma.md has the measurements behind every rule):

1. :mod:`.settings`: the record is checked (one line naming a constant channel, NaN, a transposed
   array, a sampling step outside 0.01 Hz - 1 MHz, a record too short for its band), detrended and
   scaled by one factor (no LAPACK overflow at any amplitude), its band derived from its spectrum
   (or given), decimated to the band, and the block rows, model orders and blocks chosen from the
   sampling rate, length and channels; energy up to the Nyquist frequency warns of aliasing;
2. :mod:`.core`: covariance-driven SSI (Peeters & De Roeck 1999) at each model order;
3. :mod:`.identify`: the stabilisation diagram, hierarchical clustering of its stable poles on
   frequency and MAC (Magalhães, Cunha & Caetano 2009; Reynders, Houbrechts & De Roeck 2012), the
   modes (:func:`ssi_cov`), and what to tell the user when the result is empty or partial
   (:class:`OMAWarning`, ``Modes.status``, ``Modes.messages``);
4. :mod:`.uncertainty`: standard errors of frequency, damping and shape by a delete-one-block
   jackknife of the block Toeplitz matrix, and the exact first-order perturbation of Reynders,
   Pintelon & De Roeck (2008) that it was checked against;
5. :mod:`.setups`: roving multi-setup tests merged through their reference channels (PoSER);
6. :mod:`.io`: the ``seqbayes oma`` command's record reader, modes table, JSON and diagram;
7. :mod:`.simulate`: records with known modes (a 3-D shear building at named channels).

Why our own implementation rather than pyoma-2 (1.4.3, MIT), measured on the same simulated records
(``benchmarks/bench_oma_pyoma.py``, docs/oma.md "pyoma-2"): with its defaults (20 block rows, its automated
"Magalhaes" clustering, no decimation) pyoma-2 is as accurate where it finds the modes (20 and 50 Hz records),
but returns 35 to 266 spurious modes per record (ours: none on those records), misses the 0.5 % bar for most
modes of 200 Hz records (largest errors 0.7-1.4 %), raises a LinAlgError on 2-channel records at the orders
of its examples (80), takes 15 to 32 times our CPU time, and adds pydantic, openpyxl and requests at install
time. It stays a benchmark peer in the ``bench`` extra.
"""

from .core import Poles, output_covariances, ssi_poles
from .identify import Modes, record_row, ssi_cov, stabilisation_diagram
from .settings import OMAWarning, Settings
from .setups import MergedModes, merge_setups, ssi_cov_setups
from .simulate import ModalModel, ambient_record, building_3d, modal_record

__all__ = ["Modes", "Poles", "Settings", "OMAWarning", "output_covariances", "ssi_poles", "stabilisation_diagram",
           "ssi_cov", "record_row", "MergedModes", "merge_setups", "ssi_cov_setups", "ambient_record", "ModalModel",
           "building_3d", "modal_record"]
