"""``python -m skfem_affine`` (also installed as ``skfem-affine``): see :mod:`skfem_affine.cli`."""
import sys

from skfem_affine.lab.cli import main

if __name__ == "__main__":
    sys.exit(main())
