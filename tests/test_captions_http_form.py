"""The http captioner sends the name, the category and the canonical render with a prompt stating the caption
rules (the name's colour words, compound noun and proper nouns kept; no broad category, no sizes, no mesh
facts, no ids) and holds its answers to the same caption check (the reason sent back and recorded), against the real
127.0.0.1 server of tests/test_captions_http.py; `catalog caption --captioner http` fails when every object
failed, and a connection error names the URL."""

from __future__ import annotations

import json
import socket
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image
from sqlalchemy import select
from test_captions_http import API_KEY, KEY_ENV, Behaviour, http_conf, server  # noqa: F401 - fixture

from mixcount.captions.captioning import caption_catalog
from mixcount.captions.check import check_tiers_text
from mixcount.captions.http import SYSTEM_PROMPT, HttpCaptioner
from mixcount.catalog.models import CaptionFailure, CaptionSet, CatalogObject, Render

pytestmark = pytest.mark.network

GOOD = {"short": "red fire hydrant", "concise": "Red fire hydrant with two side nozzles",
        "detailed": "A red cast fire hydrant with a domed cap and two side nozzles."}
TACKED = {"short": "large red fire hydrant furniture", "concise": "Red fire hydrant furniture with side nozzles",
          "detailed": "A red fire hydrant with a domed cap."}
MESHY = {"short": "brown juice carton", "concise": "Brown juice carton with an open surface",
         "detailed": "A brown juice carton in 3 separate parts, 69 % brown. It measures about 20 cm by 7 cm."}
CARTON = {"short": "orange juice carton", "concise": "Orange juice carton with a brown and gold print",
          "detailed": "An orange juice carton printed in brown and gold, with a white screw cap."}
TWIN = {"short": "red toy block", "concise": "Plain red toy block with rounded edges",
        "detailed": "A plain red toy block with rounded edges."}
TOLD = {"short": "red striped toy block", "concise": "Red toy block with white stripes",
        "detailed": "A red toy block with two white stripes around its middle."}
LEAKY = {"short": "white high-res bunny", "concise": "White bunny 3763 with long ears and a tail",
         "detailed": "A white bunny figure with long ears."}


def _plan(category: str, n: int, provider: str) -> tuple[int, dict[str, str], Any, float]:
    if category == "furniture":  # appends the category and a size word first, then answers in form
        return 200, {}, (TACKED if n == 0 else GOOD), 0.0
    if category == "food":  # mesh facts, a size in units and the name's colour lost first, then in form
        return 200, {}, (MESHY if n == 0 else CARTON), 0.0
    if category == "twins":  # two different objects answered alike; asked to tell apart, the second differs
        return 200, {}, (TOLD if n == 2 else TWIN), 0.0
    if category == "animal":  # leaks a source tag and an id twice: fails after the repair
        return 200, {}, LEAKY, 0.0
    return Behaviour.plan(category, n, provider)


def _objects(catalog, tmp_path, specs: list[tuple[str, str]]) -> dict[str, int]:
    ids = {}
    with catalog.session() as s:
        for i, (name, category) in enumerate(specs):
            png = tmp_path / f"r{i}.png"
            img = Image.new("RGBA", (40, 40), (0, 0, 0, 0))
            img.paste((200, 30, 30, 255), (10, 10, 30, 30))
            img.save(png)
            obj = CatalogObject(source="folder", source_id=f"o{i}", name=name, category=category,
                                model_path=str(tmp_path / "missing.glb"), dim_x=0.3, dim_y=0.3, dim_z=0.6,
                                metadata_json=json.dumps({"metadata": {"name": name}}))
            s.add(obj)
            s.flush()
            s.add(Render(object_id=obj.id, view="canonical", path=str(png), width=40, height=40))
            ids[name] = obj.id
        s.commit()
    return ids


@pytest.mark.parametrize("provider", ["openai", "gemini"])
def test_prompt_asks_for_the_form_and_answers_pass_the_caption_check(provider, server, catalog, tmp_path,  # noqa: F811
                                                                     monkeypatch):
    monkeypatch.setattr(Behaviour, "plan", staticmethod(_plan))
    monkeypatch.setenv(KEY_ENV, API_KEY)
    ids = _objects(catalog, tmp_path, [("Fire hydrant 0042 (PartNet-Mobility)", "furniture"),
                                       ("Stanford bunny (high-res)", "animal"), ("Orange juice carton", "food")])
    conf = http_conf(provider=provider, endpoint=server.base, model="vision-test-1", api_key_env=KEY_ENV,
                     timeout_s=2.0, concurrency=1, max_retries=0)
    with httpx.Client() as client:
        cap = HttpCaptioner(conf, client, sleep=lambda s: None, rng=np.random.default_rng(0))
        summary = caption_catalog(catalog, cap, concurrency=1, colour_source="model", dedupe=False)

    # the prompt states the rules: the name wins, the specific noun, no category after it, no sizes, no mesh
    # facts, no ids
    for phrase in ("The name wins where it knows", "keep its colour words", "its compound noun",
                   "the capitals of proper nouns", "never with the broad category",
                   "never add the category after the noun", "No sizes", "No facts about the 3D model",
                   "No ids"):
        assert phrase in SYSTEM_PROMPT
    first = next(r["body"] for r in server.requests if r["category"] == "furniture")
    text = json.dumps(first)
    assert "never add the category after the noun" in text
    facts_text = first["messages"][1]["content"][0]["text"] if provider == "openai" else \
        first["contents"][0]["parts"][0]["text"]
    facts = json.loads(facts_text[facts_text.index("{"):])
    # the name as the captions should say it (no id, no source tag) and the category; no dimensions, no mesh
    # facts: the canonical render goes beside them
    assert facts == {"name": "fire hydrant", "category": "furniture"}
    image = first["messages"][1]["content"][1]["image_url"]["url"] if provider == "openai" else \
        first["contents"][0]["parts"][1]["inline_data"]["data"]
    assert len(image) > 100
    bunny = next(r["body"] for r in server.requests if r["category"] == "animal")
    assert '\\"name\\": \\"Stanford bunny\\"' in json.dumps(bunny)  # the proper noun's capital kept

    # an answer out of form got one repair request naming what was wrong, and the repaired one was stored
    assert server.attempts(provider, "furniture") == 2
    repair = json.dumps([r["body"] for r in server.requests if r["category"] == "furniture"][1])
    assert "category_appended" in repair and "size_word" in repair
    # mesh facts, a size in units and the name's colour lost: rejected by the same check, the reason sent back
    assert server.attempts(provider, "food") == 2
    repair = json.dumps([r["body"] for r in server.requests if r["category"] == "food"][1])
    for kind in ("mesh_fact", "absolute_size", "name_colour_lost"):
        assert kind in repair
    # an answer still out of form after the repair is a recorded failure, not a stored caption
    assert server.attempts(provider, "animal") == 2
    assert (summary.captioned, summary.failed) == (2, 1)
    with catalog.session() as s:
        sets = {cs.object_id: cs for cs in s.scalars(select(CaptionSet))}
        failure = s.scalars(select(CaptionFailure)).one()
    assert (sets[ids["Fire hydrant 0042 (PartNet-Mobility)"]].short, failure.object_id) == (
        GOOD["short"], ids["Stanford bunny (high-res)"])
    assert "caption check" in failure.error and "id_fragment" in failure.error
    # what was stored passes the same check the stub's captions pass
    assert summary.caption_check["objects_warned"] == 0 and summary.caption_check["objects_checked"] == 2
    assert sets[ids["Orange juice carton"]].short == "orange juice carton"
    assert check_tiers_text(TACKED, name="Fire hydrant", category="furniture", captioner="http")


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_cli_fails_when_every_object_failed_and_names_the_url(server, catalog, db_url, tmp_path,  # noqa: F811
                                                               monkeypatch, capsys):
    from mixcount.cli import main

    monkeypatch.setenv(KEY_ENV, API_KEY)
    _objects(catalog, tmp_path, [("Hammer", "unauthorized"), ("Desk lamp", "unauthorized")])
    db = db_url.removeprefix("sqlite:///")
    base = ["--db", db, "--set", "captions.model=m", "--set", "captions.provider=openai",
            "--set", f"captions.api_key_env={KEY_ENV}", "--set", "captions.max_retries=0"]
    rc = main(base + ["--set", f"captions.endpoint={server.base}", "catalog", "caption", "--captioner", "http"])
    captured = capsys.readouterr()
    assert rc != 0
    assert "every object failed to caption (2 of 2" in captured.err and "HTTP 401" in captured.err
    assert API_KEY not in captured.out + captured.err

    url = f"http://127.0.0.1:{_closed_port()}"
    rc = main(base + ["--set", f"captions.endpoint={url}", "--set", "captions.timeout_s=2", "catalog", "caption",
                      "--captioner", "http"])
    captured = capsys.readouterr()
    assert rc != 0
    assert f"connection error to {url}/v1/chat/completions" in captured.err
    with catalog.session() as s:
        errors = [f.error for f in s.scalars(select(CaptionFailure))]
    assert sum(f"{url}/v1/chat/completions" in e for e in errors) == 2


@pytest.mark.parametrize("provider", ["openai", "gemini"])
def test_different_objects_with_equal_answers_are_asked_to_tell_apart(provider, server, catalog, tmp_path,  # noqa: F811
                                                                        monkeypatch):
    """Two different objects (different files) the model captioned alike: before any collision is flagged,
    the second is asked again with the first's captions to differ from; its new answer passes the same check
    and nothing is excluded."""
    monkeypatch.setattr(Behaviour, "plan", staticmethod(_plan))
    monkeypatch.setenv(KEY_ENV, API_KEY)
    _objects(catalog, tmp_path, [("Toy block", "twins"), ("Toy block", "twins")])
    with catalog.session() as s:  # two files, not one file twice
        objs = s.scalars(select(CatalogObject).order_by(CatalogObject.id)).all()
        for i, obj in enumerate(objs):
            obj.content_hash = f"hash{i}"
        s.commit()
        first_id, second_id = objs[0].id, objs[1].id
    conf = http_conf(provider=provider, endpoint=server.base, model="vision-test-1", api_key_env=KEY_ENV,
                     timeout_s=2.0, concurrency=1, max_retries=0)
    with httpx.Client() as client:
        cap = HttpCaptioner(conf, client, sleep=lambda s: None, rng=np.random.default_rng(0))
        summary = caption_catalog(catalog, cap, concurrency=1, colour_source="model")
    assert server.attempts(provider, "twins") == 3 and summary.variants_toned == 1
    asked = json.dumps([r["body"] for r in server.requests if r["category"] == "twins"][2])
    assert "already have exactly these captions" in asked and TWIN["concise"] in asked
    assert (summary.collision_pairs, summary.excluded) == (0, 0)
    with catalog.session() as s:
        sets = {cs.object_id: cs for cs in s.scalars(select(CaptionSet).where(CaptionSet.active.is_(True)))}
        statuses = {o.id: o.status for o in s.scalars(select(CatalogObject))}
    assert sets[first_id].short == TWIN["short"] and sets[second_id].short == TOLD["short"]
    assert set(statuses.values()) == {"active"}
