"""The mesh-to-NMR builder, ``python -m svr.data.build input=MESHES out=DATA`` / ``sdfdiff-build``
(configs/build.yaml, whose comments show the command lines): turns a folder of meshes (ShapeNetCore
v1 or v2, or ``<category>/<name>.obj|off|ply|stl|glb``) into the NMR format that ``svr.nmr.format``
reads, with a manifest row per mesh (``svr.data.build.dataset.build_dataset``). A mistake in the
settings or files is one line ``sdfdiff-build: error: ...`` with exit status 2; a mesh that cannot be
built is a skipped row, counted at the end."""
from __future__ import annotations

from sdfcommon.tooling.commands import hydra_entry
from svr.data.build.dataset import MANIFEST_FILE, BuildReport, build_dataset
from svr.data.build.settings import BuildSettings


def run(settings: BuildSettings) -> BuildReport:
    """Builds the folder and prints what it made."""
    report = build_dataset(settings)
    if report.already_built:
        print(f"{report.out} already holds this build ({report.built} objects); nothing to do")
        return report
    n_skipped = sum(report.skipped.values())
    print(f"built {report.built} objects, skipped {n_skipped}, left out {report.left_out} -> {report.out}")
    for reason, count in sorted(report.skipped.items(), key=lambda kv: -kv[1])[:5]:
        print(f"  skipped {count}: {reason}")
    if n_skipped or report.left_out:
        print(f"  every mesh's row: {report.out / MANIFEST_FILE}")
    return report


main = hydra_entry("build", run)


if __name__ == "__main__":
    main()


__all__ = ["run", "main"]
