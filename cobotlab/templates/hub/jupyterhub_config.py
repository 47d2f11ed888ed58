# A course hub on one machine: JupyterHub (configurable-http-proxy in front), real Unix
# accounts through PAM, every user's server started as that user from the course's Python
# environment, nbgrader's exchange, and the course's grading account running formgrader as a
# hub service that the instructors and TAs reach through the hub.
#
# Used as written: every setting comes from cobotlab_hub.toml beside this file (docs/hub.md
# writes it). Copy this file, do not edit it: a new cobotlab release may bring a new one.
# nbgrader's page on JupyterHub: https://nbgrader.readthedocs.io/en/stable/configuration/
# jupyterhub_config.html
import json
import os
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:   # cobotlab's own requirement on 3.10
    import tomli as tomllib

c = get_config()  # noqa: F821  (JupyterHub's config loader defines it)

HERE = Path(__file__).resolve().parent
SETTINGS_FILE = HERE / "cobotlab_hub.toml"
with open(SETTINGS_FILE, "rb") as f:
    S = tomllib.load(f)


def setting(name, kind=str):
    """A setting of cobotlab_hub.toml, with an error naming the file and the key."""
    if name not in S:
        raise SystemExit(f"{SETTINGS_FILE}: no setting {name!r} (docs/hub.md lists them)")
    value = S[name]
    if not isinstance(value, kind):
        raise SystemExit(f"{SETTINGS_FILE}: {name} = {value!r} should be a {kind.__name__}")
    return value


COURSE_ID = setting("course_id")
GRADER = setting("grader_account")        # the Unix account that owns the course folder
COURSE_DIR = setting("course_dir")        # `cobotlab course init` made it, as GRADER
ENV = Path(setting("environment"))        # the Python environment every server runs from
INSTRUCTORS = setting("instructors", list)
TAS = setting("tas", list)
STUDENTS = setting("students", list)
for name in (GRADER, *INSTRUCTORS, *TAS, *STUDENTS):
    if not isinstance(name, str) or not name:
        raise SystemExit(f"{SETTINGS_FILE}: {name!r} is not a Unix user name")

# ---------------------------------------------------------------------- the exchange
# THE ONE PLACE that says how assignments travel between students and the course. Every
# server (each student's, the grading service's) reads the nbgrader_config.py written here,
# through JUPYTER_CONFIG_PATH; the course's own nbgrader_config.py (from `cobotlab course init
# --exchange`) names the same folder and classes. The exchange is cobotlab's private one
# (autograder.exchange, docs/exchange.md): root laid it out with `cobotlab course exchange`,
# one inbound and one feedback folder per student, so no student can list, read, replace or
# delete another's submission or feedback.
from autograder.exchange import config_block, layout_problem  # noqa: E402

EXCHANGE_ROOT = setting("exchange_root")
NOT_PRIVATE = layout_problem(EXCHANGE_ROOT, COURSE_ID)
if NOT_PRIVATE:
    raise SystemExit(f"{SETTINGS_FILE}: exchange_root: {NOT_PRIVATE}")
NBGRADER_EXCHANGE_CONFIG = "c = get_config()  # noqa: F821\n" + config_block(EXCHANGE_ROOT,
                                                                               COURSE_ID)
# ------------------------------------------------------------------ end of the exchange

# What every server reads besides the user's own ~/.jupyter: nbgrader's exchange settings,
# rewritten at each start so that they always follow the settings file; and terminals that
# keep the server's PATH (a login shell would reset it from /etc/profile, losing the
# course environment's `cobotlab` and `nbgrader`).
SHARED_CONFIG = HERE / "jupyter-config"
SHARED_CONFIG.mkdir(mode=0o755, exist_ok=True)
(SHARED_CONFIG / "nbgrader_config.py").write_text(NBGRADER_EXCHANGE_CONFIG)
TERMINALS = {"terminado_settings": {"shell_command": ["/bin/bash"]}}
(SHARED_CONFIG / "jupyter_server_config.json").write_text(json.dumps({"ServerApp": TERMINALS}))
# Students see the Assignments tab, not formgrader or the assignment-creation tools (those
# run in the grading service below). The lab extension reads this from labconfig/.
STUDENT_CONFIG = HERE / "jupyter-config-students"
(STUDENT_CONFIG / "labconfig").mkdir(mode=0o755, parents=True, exist_ok=True)
(STUDENT_CONFIG / "nbgrader_config.py").write_text(NBGRADER_EXCHANGE_CONFIG)
(STUDENT_CONFIG / "labconfig" / "page_config.json").write_text(json.dumps({
    "disabledExtensions": {"@jupyter/nbgrader:formgrader": True,
                           "@jupyter/nbgrader:create-assignment": True,
                           "@jupyter/nbgrader:course-list": True}}))
(STUDENT_CONFIG / "jupyter_server_config.json").write_text(json.dumps({
    "ServerApp": {**TERMINALS, "jpserver_extensions": {
        "nbgrader.server_extensions.formgrader": False,
        "nbgrader.server_extensions.course_list": False}}}))

# ---------------------------------------------------------------------- the hub
c.JupyterHub.ip = setting("ip")
c.JupyterHub.port = setting("port", int)
c.JupyterHub.hub_ip = "127.0.0.1"
c.JupyterHub.hub_port = setting("hub_api_port", int)
c.ConfigurableHTTPProxy.api_url = f"http://127.0.0.1:{setting('proxy_api_port', int)}"
c.ConfigurableHTTPProxy.command = [setting("proxy_command")]
# The hub's database and cookie secret, for root only (the folder above is readable: every
# server reads its config folder from it).
PRIVATE = HERE / "private"
PRIVATE.mkdir(mode=0o700, exist_ok=True)
os.chmod(PRIVATE, 0o700)
c.JupyterHub.db_url = f"sqlite:///{PRIVATE / 'jupyterhub.sqlite'}"
c.JupyterHub.cookie_secret_file = str(PRIVATE / "jupyterhub_cookie_secret")
c.JupyterHub.pid_file = str(PRIVATE / "jupyterhub.pid")

# Real Unix accounts, their passwords checked by PAM (the hub runs as root).
c.JupyterHub.authenticator_class = "pam"
c.Authenticator.allowed_users = set(INSTRUCTORS + TAS + STUDENTS)
c.Authenticator.admin_users = set(INSTRUCTORS)

# Each user's JupyterLab runs as that user, from the course environment.
c.JupyterHub.spawner_class = "localprocess"
c.Spawner.cmd = [str(ENV / "bin" / "jupyterhub-singleuser")]
c.Spawner.default_url = "/lab"
c.Spawner.notebook_dir = "~"
c.Spawner.start_timeout = 60
c.Spawner.http_timeout = 60


def _config_path(spawner):
    """Students get the student config folder (no formgrader), everyone else the shared one."""
    return str(STUDENT_CONFIG if spawner.user.name in STUDENTS else SHARED_CONFIG)


c.Spawner.environment = {"JUPYTER_CONFIG_PATH": _config_path,
                         "PATH": f"{ENV / 'bin'}:/usr/bin:/bin"}

# ---------------------------------------------------------------------- grading
# The course's grading account runs one JupyterLab as a hub service, in the course folder,
# with formgrader in it. Only the group formgrade-<course> may open it: its role grants
# exactly access:services!service=<course>. The service's own token needs no scope beyond
# the default (it identifies users; it does not manage them).
GRADING_PORT = setting("grading_port", int)
c.JupyterHub.load_groups = {
    f"formgrade-{COURSE_ID}": {"users": INSTRUCTORS + TAS},
    f"nbgrader-{COURSE_ID}": {"users": STUDENTS},
}
c.JupyterHub.load_roles = [
    {"name": f"formgrade-{COURSE_ID}", "groups": [f"formgrade-{COURSE_ID}"],
     "scopes": [f"access:services!service={COURSE_ID}"]},
]
c.JupyterHub.services = [{
    "name": COURSE_ID,
    "url": f"http://127.0.0.1:{GRADING_PORT}",
    "command": [str(ENV / "bin" / "jupyterhub-singleuser"), "--ServerApp.ip=127.0.0.1",
                f"--ServerApp.port={GRADING_PORT}", "--ServerApp.port_retries=0",
                f"--ServerApp.root_dir={COURSE_DIR}"],
    "user": GRADER,
    "cwd": COURSE_DIR,
    "environment": {"JUPYTER_CONFIG_PATH": str(SHARED_CONFIG),
                    "JUPYTERHUB_DEFAULT_URL": "/lab",
                    "PATH": f"{ENV / 'bin'}:/usr/bin:/bin",
                    "HOME": os.path.expanduser(f"~{GRADER}")},
    "oauth_no_confirm": True,
}]
