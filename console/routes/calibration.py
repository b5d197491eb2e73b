"""Calibrating a deployment's tau from the operator's own photos (``console.calibration``)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, File, Form, Path, Request, UploadFile
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from console.calibration import (
    DEPLOYMENTS,
    MAX_PHOTOS,
    MIN_DIFFERENT_PAIRS,
    MIN_OBJECTS,
    MIN_SAME_PAIRS,
    MIN_VIEWS_PER_OBJECT,
    CalibrationInputError,
    LabelledPhoto,
    tau_in_force,
)
from console.context import Console
from console.deps import ConsoleDep, TokenDep, check_token, error
from console.jsonio import json_safe
from console.photos import PhotoError, decode_photo

router = APIRouter(prefix="/api/calibration", tags=["calibration"])

DeploymentParam = Path(pattern="^(sim|stretch)$", description="the deployment whose tau is calibrated")
JobParam = Path(pattern="^[0-9a-f]{12}$")


def _job(console: Console, job_id: str) -> Any:
    job = console.calibrator.get(job_id)
    if job is None:
        raise error(404, "unknown_calibration", f"no calibration {job_id!r}")
    return job


LIMITS = {
    "min_objects": MIN_OBJECTS,
    "min_views_per_object": MIN_VIEWS_PER_OBJECT,
    "min_same_pairs": MIN_SAME_PAIRS,
    "min_different_pairs": MIN_DIFFERENT_PAIRS,
    "max_photos": MAX_PHOTOS,
}


@router.get("", summary="Each deployment's tau in force and where it comes from, and the photo set's limits")
def calibration_status(console: ConsoleDep) -> dict[str, Any]:
    status = {d: tau_in_force(console.data_dir, d) for d in DEPLOYMENTS}
    return json_safe(status | {"busy": console.calibrator.busy, "limits": LIMITS})


@router.post(
    "/{deployment}", status_code=202, summary="Score every pair of the photos and propose tau (runs in the background)"
)
async def start_calibration(
    request: Request,
    console: ConsoleDep,
    photos: Annotated[list[UploadFile], File(description="the photos, several of each object")],
    objects: Annotated[list[str], Form(description="for each photo, in the same order, the name of its object")],
    deployment: str = DeploymentParam,
    token: Annotated[str | None, Form(description="the console token when it is required")] = None,
) -> JSONResponse:
    check_token(console, request, token)
    if len(objects) != len(photos):
        raise error(422, "bad_labels", f"{len(photos)} photos but {len(objects)} object names: give one name per photo")
    if console.manager.active_run_id is not None:
        raise error(409, "run_active", "a run is active: calibrate when the robot is idle (they share the matcher)")
    if console.calibrator.busy:
        raise error(409, "calibration_running", "a calibration is already running")
    labelled = []
    for upload, label in zip(photos, objects):
        label = label.strip()
        if not label or len(label) > 80:
            raise error(422, "bad_labels", "each photo needs an object name of 1-80 characters")
        data = await upload.read(console.config.photo_limits.max_bytes + 1)
        name = (upload.filename or "photo")[-80:]
        try:
            photo = await run_in_threadpool(decode_photo, data, console.config.photo_limits)
        except PhotoError as exc:
            raise error(exc.status, exc.code, f"{name} ({label}): {exc}") from None
        labelled.append(LabelledPhoto(label, name, photo))
    try:
        job = await run_in_threadpool(console.calibrator.start, deployment, labelled)
    except CalibrationInputError as exc:
        raise error(422, exc.code, str(exc)) from None
    except RuntimeError as exc:
        raise error(409, "calibration_running", str(exc)) from None
    return JSONResponse(json_safe(job.view()), status_code=202, headers={"location": f"/api/calibration/jobs/{job.id}"})


@router.get("/jobs", summary="The recent calibrations, newest first (without curves and pair scores)")
def calibration_jobs(console: ConsoleDep) -> dict[str, Any]:
    return json_safe({"jobs": [job.summary() for job in console.calibrator.jobs()]})


@router.get("/jobs/{job_id}", summary="A calibration's progress and, when done, its curves and proposed tau")
def calibration_job(console: ConsoleDep, job_id: str = JobParam) -> dict[str, Any]:
    return json_safe(_job(console, job_id).view())


@router.post(
    "/jobs/{job_id}/save",
    summary="Put the proposed tau in force for the job's deployment (refused when the proposal has problems)",
    dependencies=[TokenDep],
)
def save_calibration(console: ConsoleDep, job_id: str = JobParam) -> dict[str, Any]:
    job = _job(console, job_id)
    try:
        out = console.calibrator.save(job)
    except CalibrationInputError as exc:
        raise error(409, exc.code, str(exc)) from None
    return json_safe(out | {"in_force": tau_in_force(console.data_dir, job.deployment)})


@router.post(
    "/{deployment}/undo",
    summary="Undo the last save: put back the tau in force before it",
    dependencies=[TokenDep],
)
def undo_calibration(console: ConsoleDep, deployment: str = DeploymentParam) -> dict[str, Any]:
    try:
        out = console.calibrator.undo(deployment)
    except CalibrationInputError as exc:
        raise error(409, exc.code, str(exc)) from None
    return json_safe(out | {"in_force": tau_in_force(console.data_dir, deployment)})
