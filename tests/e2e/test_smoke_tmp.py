import pytest
from tests.e2e.helpers import login, open_run, shot

pytestmark = pytest.mark.e2e

def test_open(server, context, run_id):
    page = context.new_page()
    login(page, server)
    open_run(page, server, run_id)
    shot(page, "smoke")
