"""The C side of the kernel's API: the model struct, the tick loop and the accessors.

Only arrays move here; every computation is in the translated functions the loop calls
(`{tick}`: noise, angles, sensors, controller; `{integrate}`: the RK4 tick), in the order of
the numba `advance` (feed_twin.sim.kernel). `ft_outputs_now` runs the first half of the next
tick (sensors, controller) on copies of the controller state and sensor ring: the samples and
commands at the current instant, which the next tick recomputes alike. The parameters are
copied into local arrays for a run: stores into the model's arrays then cannot alias them, and
the C compiler hoists what depends on parameters alone out of the loop, as LLVM does with the
numba kernel's tuples.
"""

LOOP_C = r"""
struct ft_model {{
    double x[FT_N_X], p[FT_N_P], cp[FT_N_CP], cs[FT_N_CS], aux[FT_N_A];
    double ring[RING * FT_MEAS_SIZE], out[FT_OUT_SIZE], meas[FT_MEAS_SIZE];
    double ref[FT_REF_SIZE], drive[FT_OUT_SIZE], ext[FT_N_EXT], status[4];
    int64_t k;
}};
static const int ft_structure[{n_structure}] = {{{structure}}};

double ft_base_period(void) {{ return ft_h; }}

void ft_reset(ft_model *m)
{{
    memcpy(m->x, ft_x0, sizeof m->x);
    memcpy(m->cs, ft_cs0, sizeof m->cs);
    memset(m->ring, 0, sizeof m->ring);
    memset(m->out, 0, sizeof m->out);
    memset(m->meas, 0, sizeof m->meas);
    memset(m->status, 0, sizeof m->status);
    m->k = 0;
}}

ft_model *ft_create(void)
{{
    ft_model *m = calloc(1, sizeof *m);
    if (!m) return NULL;
    memcpy(m->p, ft_p0, sizeof m->p);
    memcpy(m->cp, ft_cp0, sizeof m->cp);
    ft_reset(m);
    return m;
}}

void ft_free(ft_model *m) {{ free(m); }}

const char *ft_name(int what, int i)
{{
    static const char *const *const lists[] = {{ft_names_x, ft_names_p, ft_names_cp, ft_names_cs,
                                               ft_names_aux, ft_names_rec}};
    if (what < 0 || what > 5 || i < 0) return 0;
    for (int j = 0; j <= i; ++j)
        if (!lists[what][j]) return 0;
    return lists[what][i];
}}

int ft_set_param(ft_model *m, int i, double value)
{{
    if (i < 0 || i >= FT_N_P) return -1;
    m->p[i] = value;
    {fill}(m->p);
    return 0;
}}

int ft_set_ctrl_param(ft_model *m, int i, double value)
{{
    if (i < 0 || i >= FT_N_CP) return -1;
    for (int j = 0; j < {n_structure}; ++j)
        if (ft_structure[j] == i && value != m->cp[i]) return -2;
    m->cp[i] = value;
    return 0;
}}

double ft_param(const ft_model *m, int i) {{ return (i >= 0 && i < FT_N_P) ? m->p[i] : NAN; }}
double ft_ctrl_param(const ft_model *m, int i)
{{
    return (i >= 0 && i < FT_N_CP) ? m->cp[i] : NAN;
}}
void ft_set_states(ft_model *m, const double *x) {{ memcpy(m->x, x, sizeof m->x); }}
void ft_set_ref(ft_model *m, const double *ref) {{ memcpy(m->ref, ref, sizeof m->ref); }}
void ft_set_drive(ft_model *m, const double *d) {{ memcpy(m->drive, d, sizeof m->drive); }}
void ft_set_ext(ft_model *m, const double *ext) {{ memcpy(m->ext, ext, sizeof m->ext); }}
int64_t ft_tick(const ft_model *m) {{ return m->k; }}
const double *ft_states(const ft_model *m) {{ return m->x; }}
const double *ft_meas(const ft_model *m) {{ return m->meas; }}
const double *ft_out(const ft_model *m) {{ return m->out; }}
const double *ft_ctrl_states(const ft_model *m) {{ return m->cs; }}
const double *ft_ctrl_params(const ft_model *m) {{ return m->cp; }}

int ft_set_ctrl_state(ft_model *m, int i, double value)
{{
    if (i < 0 || i >= {n_cs_real}) return -1;
    m->cs[i] = value;
    return 0;
}}
const double *ft_status(const ft_model *m) {{ return m->status; }}

const double *ft_aux(ft_model *m)
{{
    double sw[3] = {{0.0, 0.0, 0.0}};
    {outputs}((double)m->k * ft_h, m->x, m->p, m->out, m->ext, sw, m->aux);
    return m->aux;
}}

int64_t ft_run(ft_model *m, int64_t n, const double *ref, const double *drive,
               const double *ext, double *rec)
{{
    double pt[FT_N_P], cpt[FT_N_CP], mraw[FT_MEAS_SIZE], mdelay[FT_MEAS_SIZE], edges[16];
    double sw[3] = {{0.0, 0.0, 0.0}};
    const double h = ft_h;
    memcpy(pt, m->p, sizeof pt);
    memcpy(cpt, m->cp, sizeof cpt);
{load_x}
    for (int64_t j = 0; j < n; ++j) {{
        const int64_t k = m->k + j;
        double *r = (double *)(ref ? ref + j * FT_REF_SIZE : m->ref);
        double *dr = (double *)(drive ? drive + j * FT_OUT_SIZE : m->drive);
        double *e = (double *)(ext ? ext + j * FT_N_EXT : m->ext);
{decl_tr}
        {tick}(k, h, {x_args}, pt, cpt, m->cs, r, dr, e, ft_seed, m->ring, m->out, m->meas,
               mraw, mdelay, sw, {tr_out});
        if (rec) {{
            double *row = rec + j * FT_N_REC;
{rec_x}
            {outputs}((double)k * h, row, pt, m->out, e, sw, m->aux);
            memcpy(row + FT_N_X, m->aux, {n_a} * sizeof(double));
            memcpy(row + FT_N_X + {n_a}, m->meas, FT_MEAS_SIZE * sizeof(double));
            memcpy(row + FT_N_X + {n_a} + FT_MEAS_SIZE, m->out, FT_OUT_SIZE * sizeof(double));
            memcpy(row + FT_N_X + {n_a} + FT_MEAS_SIZE + FT_OUT_SIZE, m->cs,
                   {n_cs_real} * sizeof(double));
        }}
        {integrate}((double)k * h, h, {x_args}, pt, m->out, e, sw, edges, {tr_args}, {x_out});
        const double xnew[FT_N_X] = {{{x_args}}};
        for (int i = 0; i < FT_N_X; ++i) {{
            if (!(fabs(xnew[i]) <= ft_xlim[i])) {{
                memcpy(m->x, xnew, sizeof m->x);
                m->status[0] = 1.0;
                m->status[1] = (double)k;
                m->status[2] = (double)i;
                m->status[3] = xnew[i];
                m->k = k + 1;
                return j + 1;
            }}
        }}
    }}
{store_x}
    m->k += n;
    return n;
}}

int64_t ft_step(ft_model *m, int64_t n) {{ return ft_run(m, n, 0, 0, 0, 0); }}

void ft_outputs_now(const ft_model *m, double *meas, double *out)
{{
    double cs[FT_N_CS], ring[RING * FT_MEAS_SIZE], mraw[FT_MEAS_SIZE], mdelay[FT_MEAS_SIZE];
    double sw[3] = {{0.0, 0.0, 0.0}};
    double p[FT_N_P], cp[FT_N_CP], ref[FT_REF_SIZE], drive[FT_OUT_SIZE], ext[FT_N_EXT];
    memcpy(cs, m->cs, sizeof cs);
    memcpy(ring, m->ring, sizeof ring);
    memcpy(p, m->p, sizeof p);
    memcpy(cp, m->cp, sizeof cp);
    memcpy(ref, m->ref, sizeof ref);
    memcpy(drive, m->drive, sizeof drive);
    memcpy(ext, m->ext, sizeof ext);
    memcpy(out, m->out, FT_OUT_SIZE * sizeof(double));
{load_x}
    {{
{decl_tr}
        {tick}(m->k, ft_h, {x_args}, p, cp, cs, ref, drive, ext, ft_seed, ring, out, meas, mraw,
               mdelay, sw, {tr_out});
    }}
}}
"""
