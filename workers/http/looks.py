"""A ``POST .../looks`` body parsed into paint settings (prompts, photos, a repainted template or a
textured member) and its bounds over HTTP; the service paints and stores the look
(:meth:`proctex.serve.service.FamilyService.add_look`)."""

from __future__ import annotations

from typing import Any

from proctex.serve.service import BadInput, TooLarge

#: A look's texture size over HTTP (the CLI allows up to 8192): a request paints seconds, not minutes.
MAX_LOOK_TEXTURE = 2048


#: photos one look may carry over HTTP (multipart file fields ``image.<part>``).
MAX_LOOK_PHOTOS = 8
#: a photo look's or a repainted template GLB's whole multipart body, at most (each photo's pixels
#: are bounded from its header).
MAX_LOOK_BODY = 64 * 2**20


def parse_photos(body: dict[str, Any], files: dict[str, tuple[bytes, str]], under_prompt: bool) -> tuple[dict[str, dict], dict[str, Any]]:
    """The ``images`` entries and photos of a look request: ``files`` (part -> bytes, name), each
    read by :func:`proctex.texture.exemplar.read_photo` (pixels checked from the header before
    decoding), and ``body["images"]`` (optional: part -> ``{"scale", "rotate", "normal",
    "roughness"}``), which may name only parts sent a photo."""
    from proctex.texture.photo import read_photo

    settings = body.get("images") or {}
    if not isinstance(settings, dict) or not all(isinstance(v, dict) for v in settings.values()):
        raise BadInput("images must be an object {part: {scale, rotate, normal, roughness}}")
    extra = sorted(set(settings) - set(files))
    if extra:
        raise BadInput(f"images names {', '.join(repr(str(k)[:40]) for k in extra[:5])}, sent no photo (a file field image.<part>)")
    images, photos = {}, {}
    for part, (data, name) in files.items():
        given = settings.get(part, {})
        unknown = set(given) - {"scale", "rotate", "normal", "roughness"}
        if unknown:
            raise BadInput(f"photo {part[:40]!r}: unknown settings {sorted(map(str, unknown))[:5]}; a photo takes scale, rotate, normal, roughness")
        photos[part] = read_photo(data, name=name)
        images[part] = {"file": name, **given, **({"under_prompt": under_prompt} if part == "*" else {})}
    return images, photos


def parse_look(body: dict[str, Any], svc: Any, files: dict[str, tuple[bytes, str]] | None = None) -> tuple[str, Any, bool, dict[str, Any]]:
    """``(name, PaintConfig, force, photos)`` of a ``POST .../looks`` body: the build's paint settings
    with the body's ``prompt`` (at most ``max_prompt`` characters; required unless photos are sent),
    ``group_prompts``, ``painter``, ``texture_size`` (16..:data:`MAX_LOOK_TEXTURE`) and, with photo
    files (:func:`read_look_request`), ``images`` over them (:class:`BadInput` naming what is wrong)."""
    from proctex.store.layout import check_look_name
    from proctex.store.looks import new_look_paint

    files = dict(files or {})
    glb = files.pop("glb", None)
    member_params, member = body.get("params"), bool(body.get("member", False))
    if glb is not None:
        if files or set(body) - {"name", "texture_size", "force", "params", "member"}:
            raise BadInput("a look from a GLB takes only name, texture_size, force and (a textured member of the family) params or member, and no photos")
        if member_params is not None and not isinstance(member_params, dict):
            raise BadInput("params must be an object of the member's parameter values")
        if not isinstance(body.get("member", False), bool):
            raise BadInput("member must be true or false")
        body = {k: v for k, v in body.items() if k not in ("params", "member")}
    elif "params" in body or "member" in body:
        raise BadInput("params and member go with a 'glb' file (a textured member of the family)")
    unknown = set(body) - {"name", "prompt", "group_prompts", "part_words", "painter", "texture_size", "force", "images"}
    if unknown:
        raise BadInput(f"unknown fields {sorted(unknown)[:5]}; a look takes name, prompt, group_prompts, part_words, painter, texture_size, force, images")
    name, prompt = body.get("name"), body.get("prompt")
    check_look_name(name)
    if (files or glb is not None) and prompt is None:
        pass  # a look from photos alone (the build's prompt covers what no photo does) or from a GLB
    elif not isinstance(prompt, str) or not prompt.strip() or len(prompt) > svc.limits.max_prompt:
        raise BadInput(f"prompt must be text of 1 to {svc.limits.max_prompt} characters")
    prompts = body.get("group_prompts") or {}
    if not isinstance(prompts, dict) or len(prompts) > 256 or not all(isinstance(k, str) and isinstance(v, str) and len(k) <= 64 and len(v) <= svc.limits.max_prompt for k, v in prompts.items()):
        raise BadInput(f"group_prompts must be an object of at most 256 prompts of at most {svc.limits.max_prompt} characters")
    size = body.get("texture_size")
    if size is not None and (isinstance(size, bool) or not isinstance(size, int) or not 16 <= size <= MAX_LOOK_TEXTURE):
        raise BadInput(f"texture_size must be an integer in [16, {MAX_LOOK_TEXTURE}], got {str(size)[:40]}")
    force = body.get("force", False)
    if not isinstance(force, bool):
        raise BadInput("force must be true or false")
    try:
        words = body.get("part_words") or {}
        if not isinstance(words, dict):
            raise BadInput("part_words must be an object {group index: word}")
        images, photos = parse_photos(body, files, under_prompt=prompt is not None) if files else ({}, {})
        if body.get("images") and not files:
            raise BadInput("images are settings of photos: send them as multipart file fields image.<part>")
        glb_record = None
        if glb is not None:
            from proctex.store.layout import digest

            if len(glb[0]) > MAX_LOOK_BODY:
                raise TooLarge(f"the GLB is over the limit of {MAX_LOOK_BODY} bytes")
            glb_record = {"name": glb[1], "sha256": digest(glb[0])}
            photos = {"glb": glb[0]}
            if member_params is not None or member:
                photos["member"] = {"glb": glb[0], "params": member_params}
        paint = new_look_paint(svc.config.paint, prompt, prompts, body.get("painter"), size, part_words=words, images=images, glb=glb_record)
    except (TypeError, ValueError) as exc:
        raise BadInput(str(exc)[:500]) from exc
    return name, paint, force, photos
