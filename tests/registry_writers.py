"""test_registry's registry writers, each run in a spawned process: a module of its own, so a
child imports what recording a parameter file needs and not the whole test module (fieldcal's
command line, the acceptance specs, the PostgreSQL fixture: 0.16 s of CPU a child, five children
a backend)."""
from __future__ import annotations

import hashlib
import itertools

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.model import k_from_params
from fieldcal.paramfile import ParameterFile, save
from fieldcal.registry import Registry
from fieldcal.units import STANDARD_GRAVITY

MG = STANDARD_GRAVITY * 1e-3


def unit_file(path, serial, bias_mg, sigma_mg=0.03):
    theta = np.r_[np.array(bias_mg) * MG, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    cal = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="powell",
                      K=k_from_params(theta), bias=theta[:3],
                      sigma=np.r_[[sigma_mg * MG] * 3, [1e-5] * 6], residual_rms=1e-4)
    pf = ParameterFile.build((cal,), station=Station(40.0, 50.0), procedure="field-18", method="powell",
                             input_sha256=hashlib.sha256(str((serial, bias_mg)).encode()).hexdigest(),
                             device_name="MIMU-9", device_serial=serial)
    return save(pf, path)


def writer(db, files, go):
    assert go.wait(60), "the parent never said go"  # (a failed assert: exit code 1, which the parent checks)
    with Registry(db) as registry:  # the first to open an empty registry migrates it
        for f in files:
            registry.record(f)


def endless_writer(db, files, first_done):
    """Records ``files``, then new ones for ever: only the kill ends it, wherever it lands."""
    with Registry(db) as registry:
        for i, f in enumerate(files):
            registry.record(f)
            if i == 4:
                first_done.set()
        for i in itertools.count(len(files)):
            registry.record(unit_file(files[0].parent / f"k-{i}.yaml", f"K{i}", [i, 0.0, 0.0]))
