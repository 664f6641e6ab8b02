"""``python -m skfem_affine`` (also installed as ``skfem-affine``): the lab's commands (:mod:`skfem_affine.lab.cli`),
and ``compile``, which compiles every numba kernel into the disk cache (``skfem_affine._compile``)."""
import sys


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["compile"]:
        from skfem_affine._compile import main as compile_main
        return compile_main(argv[1:])
    from skfem_affine.lab.cli import main as lab_main
    return lab_main(argv)


if __name__ == "__main__":
    sys.exit(main())
