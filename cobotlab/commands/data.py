"""``cobotlab data``: the real datasets shipped with cobotlab (list, export), and the import
of a capture made elsewhere into a capture folder for ``cobotlab calibrate``."""

from __future__ import annotations

from cobotlab.commands import data_import


def add_parser(sub) -> None:
    data = sub.add_parser(
        "data",
        help="list the real datasets shipped with cobotlab, or copy one out",
        description="Real captures shipped inside the package, with their source and licence.",
    )
    data_sub = data.add_subparsers(dest="data_command", metavar="ACTION", required=True)
    data_sub.add_parser("list", help="name, description, source and licence of each dataset")
    export = data_sub.add_parser("export", help="copy a dataset's files (and README) to a folder")
    export.add_argument("name", metavar="NAME", help="a name from `cobotlab data list`")
    export.add_argument("dest", metavar="DIR", help="folder to copy into (created if needed)")
    data_import.add_parser(data_sub)

def run(args) -> None:
    if args.data_command == "list":
        _data_list()
    elif args.data_command == "export":
        _data_export(args.name, args.dest)
    elif args.data_command == "import":
        data_import.run(args)


def _datasets() -> dict:
    """Shipped datasets: folder name -> (folder Traversable, title, source line, licence line),
    read from each data folder's README (its title, first paragraph and Licence section)."""
    from importlib import resources

    found = {}
    root = resources.files("autograder").joinpath("data")
    for folder in sorted(root.iterdir(), key=lambda f: f.name):
        readme = folder.joinpath("README.md")
        if not readme.is_file():
            continue
        lines = readme.read_text().splitlines()
        title = next((text[2:].strip() for text in lines if text.startswith("# ")), folder.name)
        body = lines[lines.index(next(text for text in lines if text.startswith("# "))) + 1:]
        paragraph = []
        for line in body:
            if line.strip():
                paragraph.append(line.strip())
            elif paragraph:
                break
        source = " ".join(paragraph)
        licence = ""
        if "## Licence" in lines:
            after = lines[lines.index("## Licence") + 1:]
            licence = next((text.strip() for text in after if text.strip()), "")
        found[folder.name] = (folder, title, source, licence)
    return found


def _data_list() -> None:
    for name, (folder, title, source, licence) in _datasets().items():
        files = [f.name for f in folder.iterdir() if f.is_file()]
        print(f"{name}: {title}")
        print(f"  source:  {source}")
        print(f"  licence: {licence or 'see README.md'}")
        print(f"  files:   {', '.join(sorted(files))}")


def _data_export(name: str, dest) -> None:
    import shutil
    from importlib import resources
    from pathlib import Path

    datasets = _datasets()
    if name not in datasets:
        raise ValueError(f"no dataset named {name!r}; `cobotlab data list` shows: "
                         f"{', '.join(datasets) or 'none'}")
    folder = datasets[name][0]
    dest = Path(dest)
    files = [f for f in folder.iterdir() if f.is_file()]
    clashes = [f.name for f in files if (dest / f.name).exists()]
    if clashes:
        raise FileExistsError(f"{dest} already has {', '.join(clashes)}; export into an empty "
                              "folder or remove those files first")
    dest.mkdir(parents=True, exist_ok=True)
    for f in files:
        with resources.as_file(f) as source:
            shutil.copyfile(source, dest / f.name)
        print(f"copied {dest / f.name}")
