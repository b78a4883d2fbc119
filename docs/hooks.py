"""Build hooks: pages generated from files that live elsewhere in the repository.

- the example notebooks (``notebooks/``) are rendered, executed at build time in
  small mode (``DIFFIMPACT_NOTEBOOK_SMALL=1``: few points, few iterations);
- the Performance page is ``benchmarks/RESULTS.md`` itself, with its plots, so
  no measured number is typed twice;
- the Changelog page is ``CHANGELOG.md``.
"""

import os
import pathlib
import tempfile

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = pathlib.Path(__file__).resolve().parent.parent
GENERATED = {
    "performance.md": ROOT / "benchmarks" / "RESULTS.md",
    "changelog.md": ROOT / "CHANGELOG.md",
}


def on_config(config):
    # the notebooks read these; a reader's own settings win
    os.environ.setdefault("DIFFIMPACT_NOTEBOOK_SMALL", "1")
    os.environ.setdefault("DIFFIMPACT_NOTEBOOK_OUT", tempfile.mkdtemp(prefix="nb-"))
    return config


@event_priority(100)  # before mkdocs-jupyter, which converts the notebooks
def on_files(files, config):
    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        files.append(
            File(
                f"notebooks/{path.name}",
                src_dir=str(ROOT),
                dest_dir=config["site_dir"],
                use_directory_urls=config["use_directory_urls"],
            )
        )
    for name, source in GENERATED.items():
        files.append(File.generated(config, name, content=source.read_text()))
    for png in sorted((ROOT / "benchmarks").glob("*.png")):
        # RESULTS.md links its plots by bare name; the page sits at the root
        files.append(File.generated(config, png.name, abs_src_path=str(png)))
    return files
