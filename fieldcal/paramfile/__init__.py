"""The versioned parameter file a calibration produces (schema ``fieldcal-parameters/1``).

``document`` holds the data model and writing; ``loading`` the validating reader.
"""
from fieldcal.paramfile.document import (
                                         SCHEMA,
                                         ParameterFile,
                                         ParameterFileError,
                                         Provenance,
                                         TriadParameters,
                                         dump,
                                         hash_inputs,
                                         save,
                                         to_document,
)
from fieldcal.paramfile.loading import from_document, load, loads

__all__ = ["SCHEMA", "ParameterFile", "ParameterFileError", "Provenance", "TriadParameters", "dump",
           "from_document", "hash_inputs", "load", "loads", "save", "to_document"]
