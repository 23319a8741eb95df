"""Imported first by ``import ocreach``: starts OpenBLAS with the BLAS limit's thread count when
numpy is not loaded yet (:func:`ocreach.parallel.preset_blas_env`)."""
from ocreach.parallel import preset_blas_env

preset_blas_env()
