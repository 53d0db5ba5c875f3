"""The files for other tools over HTTP: results.zip, the COLMAP model, images/, the OBJ and USDZ
meshes are listed in the result and served with their types; the stored inputs still are not."""

from __future__ import annotations

from fastapi.testclient import TestClient

from app.settings import Settings
from cadnerf_core.export.bundle import write_bundle, write_images
from cadnerf_core.jobfolder import COLMAP_CAMERAS, MESH_MTL, MESH_OBJ, MESH_USDZ, JobFolder
from tests.app.test_api_jobs import _submit, _succeed
from tests.job_results import write_fake_result


def test_bundle_parts_are_listed_and_served(client: TestClient, settings: Settings,
                                            photos) -> None:
    job = _submit(client, photos)
    folder = JobFolder(_succeed(settings, job["id"]))
    images = write_images(folder)
    folder.write_text(COLMAP_CAMERAS, "1 PINHOLE 64 48 50 50 32 24\n")
    folder.write_text(MESH_OBJ, "v 0 0 0\n")
    folder.write_text(MESH_MTL, "newmtl baked\n")
    folder.file(MESH_USDZ).write_bytes(b"PK\x05\x06" + bytes(18))  # an empty zip
    members = write_bundle(folder)
    assert images[0] in members and COLMAP_CAMERAS in members and MESH_USDZ in members
    write_fake_result(folder)  # the pipeline's result comes last and lists them
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    base = f"/v1/jobs/{job['id']}/artifacts"
    expected = {"results.zip": "application/zip", COLMAP_CAMERAS: "text/plain",
                MESH_OBJ: "model/obj", MESH_MTL: "model/mtl", MESH_USDZ: "model/vnd.usdz+zip",
                images[0]: "image/png"}
    for name, media_type in expected.items():
        assert name in result["artifacts"], name
        response = client.get(f"{base}/{name}")
        assert response.status_code == 200, name
        assert response.headers["content-type"].split(";")[0] == media_type, name
    photo = folder.photos()[0]
    assert client.get(f"{base}/{images[0]}").content == photo.path.read_bytes()
    assert client.get(f"{base}/inputs/{photo.name}").status_code == 404
    assert client.get(f"{base}/images/../inputs/{photo.name}").status_code == 404
