"""The page's scenario upload kept under the data root (`services.bus.web.upload`): what is kept,
what is refused, and that a refusal keeps nothing."""

from __future__ import annotations

import io
import os
import zipfile

import pytest

from tests.conftest import ROOT
from vrsim.services.bus.web import upload

SCENARIO = os.path.join(ROOT, "scenarios", "quick_rectangle.toml")


def parts(*files: tuple[str, bytes]) -> list:
    return [(name, io.BytesIO(data)) for name, data in files]


def quick() -> bytes:
    with open(SCENARIO, "rb") as fh:
        return fh.read()


def kept(root) -> list[str]:
    home = root / upload.UPLOADS_FOLDER
    return sorted(os.listdir(home)) if home.is_dir() else []


def test_an_upload_is_kept_in_a_folder_of_its_own_and_the_newest_are_kept(tmp_path):
    first = upload.save(parts(("quick.toml", quick())), str(tmp_path))
    assert first.source == os.path.join(first.folder, "quick.toml") and first.base_dir == first.folder
    assert first.text == quick().decode()
    assert os.path.dirname(first.folder) == str(tmp_path / "runs" / "uploads")
    for _ in range(upload.KEEP_UPLOADS + 2):
        last = upload.save(parts(("quick.toml", quick())), str(tmp_path))
    folders = kept(tmp_path)
    assert len(folders) == upload.KEEP_UPLOADS and os.path.basename(last.folder) in folders
    assert not any(name.startswith(".") for name in folders)  # no partial folder left behind


@pytest.mark.parametrize(("files", "words"), [
    ([], "no files"),
    ([("a.toml", b"x"), ("a.toml", b"y")], "a.toml comes twice"),
    ([("a.toml", b"name = 'a'"), ("b.toml", b"name = 'b'")], "exactly one scenario (.toml)"),
    ([("field.geojson", b"{}")], "found none"),
    ([("x.toml", b"[field\n")], "upload: x.toml"),
    ([("x.toml", quick().replace(b'[map]\nsynthetic = "random_field"', b"[map]\nfile = '/etc/x.csv'"))],
     "outside the upload's folder"),
    ([(".hidden.toml", b"")], "only letters, digits"),
])
def test_a_bad_upload_is_refused_in_one_line_and_nothing_is_kept(tmp_path, files, words):
    with pytest.raises(upload.UploadError) as err:
        upload.save(parts(*files), str(tmp_path))
    assert words in str(err.value) and "\n" not in str(err.value)
    home = tmp_path / upload.UPLOADS_FOLDER
    assert not home.is_dir() or os.listdir(home) == []  # nothing kept, no partial folder either


def test_a_zip_of_too_many_files_or_too_much_is_refused(tmp_path):
    many = io.BytesIO()
    with zipfile.ZipFile(many, "w") as archive:
        archive.writestr("s.toml", quick())
        for k in range(upload.MAX_FILES):
            archive.writestr(f"d/{k}.csv", "x,y\n")
    with pytest.raises(upload.UploadError, match=f"more than the {upload.MAX_FILES}"):
        upload.save(parts(("many.zip", many.getvalue())), str(tmp_path))
    deep = io.BytesIO()
    with zipfile.ZipFile(deep, "w") as archive:
        archive.writestr("a/b/c/d/e/s.toml", quick())
    with pytest.raises(upload.UploadError, match="at most 4 deep"):
        upload.save(parts(("deep.zip", deep.getvalue())), str(tmp_path))
    assert os.listdir(tmp_path / upload.UPLOADS_FOLDER) == []
